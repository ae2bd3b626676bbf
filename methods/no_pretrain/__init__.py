"""Table I row "Ours w/o CLIP pre-train": Ours' backbone from random weights."""

from ocplace.methods.no_pretrain.recipe import PRESETS as PRESETS  # its entry at each experiment's scale: PRESETS[name]
from ocplace.methods.no_pretrain.recipe import NoPretrainRecipe
from ocplace.models.inference_settings import InferenceSettings

TABLE_ROW = 7
RECIPE = NoPretrainRecipe  # the type of its entry in `Experiment.recipes`
INFERENCE = InferenceSettings()  # argmax per reference: the paper's protocol
