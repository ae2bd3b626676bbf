"""Row "Ours, joint inference" (beyond the paper): Ours' trained runs, each reference grounded jointly."""

from ocplace.models.inference_settings import Decision, InferenceSettings

TABLE_ROW = 8
INFERENCE = InferenceSettings(Decision("joint"))  # top_k 5: rule J's, docs/settings.md
