"""Table I row "CLIPort-Place": an affordance map over the table's pixels."""

from ocplace.methods.cliport.recipe import CliportRecipe

TABLE_ROW = 5
RECIPE = CliportRecipe  # the type of its entry in `Experiment.recipes`
