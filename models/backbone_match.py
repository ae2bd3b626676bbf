"""Whether a backbone is the one a trained run was trained on, and where to find that one when it is not.

Above both backbone modules (it looks through the saved offline backbones), so that the generic loader
(`backbone.py`) never imports the offline tower back.
"""

from __future__ import annotations

from ocplace.errors import TrainingError
from ocplace.models.backbone import Backbone
from ocplace.models.offline_backbone import saved_backbone_with
from ocplace.paths import backbones_cache


def backbone_hint(fingerprint: str) -> str:
    """How to get the backbone with `fingerprint`: its saved directory, or how to build or pass it."""
    directory = saved_backbone_with(fingerprint)
    if directory is not None:
        return f"the backbone they were trained with is saved in {directory}: pass `--backbone offline:{directory}`"
    return (
        f"no saved offline backbone in {backbones_cache()} has that fingerprint: pass the backbone they were "
        "trained with (`--backbone SPEC`, the spec their training used), or train adapters on a backbone you "
        "have (`ocplace reproduce` pretrains its scale's backbone and trains on it)"
    )


def check_trained_on(backbone: Backbone, fingerprint: str, what: str) -> None:
    """TrainingError unless `backbone` is the one with `fingerprint`, which `what` ("the adapters in RUN were")
    was trained on; the message says where that backbone is, or how to get it. The one check every trained
    run's loader makes."""
    if backbone.fingerprint != fingerprint:
        raise TrainingError(
            f"{what} trained on features of another backbone (fingerprint {fingerprint[:12]}, this one "
            f"{backbone.fingerprint[:12]}); {backbone_hint(fingerprint)}"
        )
