"""What the two competing approaches of Table I share (docs/baselines.md): the backbone check of a trained
run, failures, descriptions and training from a context.

Both read only what eval/api.py allows: RGB-D, the record's boxes with the AABBs of those objects,
the camera, the instruction and the held object's footprint; never the tuples or the oracle.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from ocplace.eval.api import MethodOutput
from ocplace.methods.api import TrainContext

if TYPE_CHECKING:
    from collections.abc import Callable

    from ocplace.models.backbone import Backbone
    from ocplace.models.parsing.types import Parser


def load_checked_backbone(spec: str, run_meta: dict[str, Any], name: str) -> Backbone:
    from ocplace.models.backbone import check_trained_on, load_backbone

    backbone = load_backbone(spec)
    check_trained_on(backbone, run_meta["backbone_fingerprint"], f"the {name} run was")
    return backbone


def failure_output(error: Exception) -> MethodOutput:
    return MethodOutput(mode=None, samples=None, failure=f"{type(error).__name__}: {error}")


def describe_baseline(
    name: str,
    run_meta: dict[str, Any],
    weights_sha256: str,
    backbone: Backbone,
    num_samples: int,
    parser: Parser | None = None,
) -> dict[str, Any]:
    """What decides a trained baseline's placements: its run, weights, backbone, parser (if any), sample count."""
    described = {
        "method": name,
        "run": run_meta,
        "weights_sha256": weights_sha256,
        "backbone_fingerprint": backbone.fingerprint,
    }
    if parser is not None:
        described["parser"] = parser.name
    return {**described, "num_samples": num_samples}


def train_baseline(train: Callable[..., None], context: TrainContext[Any]) -> Path:
    """`train` (`train.grids.train_grids` or `train.cliport.train_cliport`) on the context's fields, unless its run
    directory holds a finished run (kept as it is)."""
    from ocplace.models.backbone import load_backbone
    from ocplace.train.baseline_runs import BaselineRun, is_finished

    if not is_finished(context.out_dir):
        backbone = load_backbone(context.backbone)
        train(
            BaselineRun(
                backbone, context.dataset_dir, context.out_dir, context.fraction, context.seed, context.experiment
            ),
            context.recipe,
        )
    return context.out_dir
