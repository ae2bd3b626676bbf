"""Row "Ours w/o Adapter, joint inference" (beyond the paper): the plain backbone, each reference grounded jointly."""

from ocplace.models.inference_settings import Decision, InferenceSettings

TABLE_ROW = 9
INFERENCE = InferenceSettings(Decision("joint"))  # top_k 5: rule J's, docs/settings.md
