"""Table I row "CLIPort-Place": an affordance map over the table's pixels."""

from ocplace.methods.cliport.recipe import PRESETS as PRESETS  # its entry at each experiment's scale: PRESETS[name]
from ocplace.methods.cliport.recipe import CliportRecipe

TABLE_ROW = 5
RECIPE = CliportRecipe  # the type of its entry in `Experiment.recipes`
