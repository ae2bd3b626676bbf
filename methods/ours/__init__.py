"""Table I row "Ours": CLIP-Adapters trained on a frozen backbone's features, placed by the policy."""

from ocplace.methods.ours.recipe import PRESETS as PRESETS  # its entry at each experiment's scale: PRESETS[name]
from ocplace.methods.ours.recipe import OursRecipe
from ocplace.models.inference_settings import InferenceSettings

TABLE_ROW = 1
RECIPE = OursRecipe  # the type of its entry in `Experiment.recipes`
INFERENCE = InferenceSettings()  # argmax per reference: the paper's protocol
