"""Row "Ours, paper's adapters": Ours with the paper's adapter recipe, beside rule A's."""

from ocplace.methods.ours.recipe import OursRecipe
from ocplace.models.inference_settings import InferenceSettings

TABLE_ROW = 2
RECIPE = OursRecipe  # the type of its entry in `Experiment.recipes`
INFERENCE = InferenceSettings()  # argmax per reference: the paper's protocol
