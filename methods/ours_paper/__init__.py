"""Row "Ours, paper's adapters": Ours with the paper's adapter recipe, beside rule A's."""

from ocplace.methods.ours.recipe import PAPER_PRESETS, OursRecipe
from ocplace.models.inference_settings import InferenceSettings

TABLE_ROW = 2
RECIPE = OursRecipe  # the type of its entry in `Experiment.recipes`
PRESETS = PAPER_PRESETS  # its entry at each experiment's scale: PRESETS[name]
INFERENCE = InferenceSettings()  # argmax per reference: the paper's protocol
