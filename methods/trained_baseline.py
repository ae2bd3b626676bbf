"""What the two competing approaches of Table I share (docs/baselines.md): a trained run loaded with its
backbone checked, failures, descriptions and training from a context.

Both read only what eval/api.py allows: RGB-D, the record's boxes with the AABBs of those objects,
the camera, the instruction and the held object's footprint; never the tuples or the oracle.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ocplace.eval.api import MethodOutput
from ocplace.methods.contract import LoadContext, TrainContext

if TYPE_CHECKING:
    from collections.abc import Callable

    from ocplace.models.backbone import Backbone
    from ocplace.models.parsing.types import Parser


@dataclasses.dataclass(frozen=True)
class TrainedRun:
    """A baseline's finished run, loaded: its parameters and record on the backbone it was trained on (checked)."""

    backbone: Backbone
    params: dict[str, Any]
    run_meta: dict[str, Any]
    weights_sha256: str
    num_samples: int

    @classmethod
    def load(cls, context: LoadContext, load_params: Callable[[Path], tuple[Any, ...]], label: str) -> TrainedRun:
        """`load_params(run_dir) -> (params, run_meta, sha256)` of the context's run, with its backbone."""
        from ocplace.models.backbone import load_backbone
        from ocplace.models.backbone_match import check_trained_on

        params, run_meta, sha = load_params(context.trained_run)
        backbone = load_backbone(context.backbone)
        check_trained_on(backbone, run_meta["backbone_fingerprint"], f"the {label} run was")
        return cls(backbone, params, run_meta, sha, context.num_samples)

    def describe(self, name: str, parser: Parser | None = None) -> dict[str, Any]:
        """What decides the baseline's placements: its run, weights, backbone, parser (if any), sample count."""
        described = {
            "method": name,
            "run": self.run_meta,
            "weights_sha256": self.weights_sha256,
            "backbone_fingerprint": self.backbone.fingerprint,
        }
        if parser is not None:
            described["parser"] = parser.name
        return {**described, "num_samples": self.num_samples}


def failure_output(error: Exception) -> MethodOutput:
    return MethodOutput(mode=None, samples=None, failure=f"{type(error).__name__}: {error}")


def train_baseline(train: Callable[..., None], context: TrainContext[Any]) -> Path:
    """`train` (`train_grids` or `train_cliport`) on the context's fields (resumable; a finished run is kept by
    `methods.contract.train_once`)."""
    from ocplace.models.backbone import load_backbone
    from ocplace.train.baseline_runs import BaselineRun

    backbone = load_backbone(context.backbone)
    run = BaselineRun(
        backbone, context.dataset_dir, context.out_dir, context.fraction, context.seed, context.experiment
    )
    train(run, context.recipe)
    return context.out_dir
