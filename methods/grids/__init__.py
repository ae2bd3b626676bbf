"""Table I row "Raw Image Grids": the table cut into cells, the best-matching cell chosen."""

from ocplace.methods.grids.recipe import PRESETS as PRESETS  # its entry at each experiment's scale: PRESETS[name]
from ocplace.methods.grids.recipe import GridsRecipe

TABLE_ROW = 4
RECIPE = GridsRecipe  # the type of its entry in `Experiment.recipes`
