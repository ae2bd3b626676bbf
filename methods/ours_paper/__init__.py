"""Row "Ours, paper's adapters": Ours with the paper's adapter recipe, beside rule A's."""

from ocplace.methods.ours.recipe import OursRecipe

TABLE_ROW = 2
RECIPE = OursRecipe  # the type of its entry in `Experiment.recipes`
