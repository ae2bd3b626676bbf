"""Table I row "Ours": CLIP-Adapters trained on a frozen backbone's features, placed by the policy."""

from ocplace.methods.ours.recipe import OursRecipe

TABLE_ROW = 1
RECIPE = OursRecipe  # the type of its entry in `Experiment.recipes`
