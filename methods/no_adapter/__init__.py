"""Table I row "Ours w/o Adapter": Ours' policy on the plain backbone; it learns nothing."""

from ocplace.models.inference_settings import InferenceSettings

TABLE_ROW = 3
INFERENCE = InferenceSettings()  # argmax per reference: the paper's protocol
