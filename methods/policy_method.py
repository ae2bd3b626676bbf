"""The placement policy as a `Method`: what Ours, Ours w/o Adapter and Ours w/o CLIP pre-train share.

They place with `PlacementPolicy.place_many`: one pipeline, the robot's (`models/policy.py`), fed
with what the harness allows a method to see (`scene_input`). Ours and w/o LLM train on the same
cached features of the training split (`prepare_train_features`).
"""

from __future__ import annotations

import dataclasses
import hashlib
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ocplace import serial
from ocplace.eval.api import MethodOutput
from ocplace.methods.contract import LoadContext, TrainContext
from ocplace.sim.dataset.records import SceneRecord

if TYPE_CHECKING:
    import jax

    from ocplace.models.policy import Placement, PlacementPolicy, SceneInput


def prepare_train_features(ctx: TrainContext[Any]) -> Path:
    """The training split's features, which Ours and no_llm read (one file per backbone and dataset)."""
    from ocplace.models.backbone import load_backbone
    from ocplace.models.features import featurize_split

    return featurize_split(Path(ctx.dataset_dir), "train", load_backbone(ctx.backbone), progress=False)


def scene_input(record: SceneRecord) -> SceneInput:
    """What a method may see of a dataset scene, as the policy's input (no tuples, no oracle)."""
    from ocplace.models.policy import SceneInput

    return SceneInput(**record.policy_inputs(), name=record.id)


def output_of(placement: Placement) -> MethodOutput:
    from ocplace.models.parsing.types import parse_note

    return MethodOutput(
        mode=None if placement.mode is None else np.asarray(placement.mode, np.float64),
        samples=None if placement.samples is None else np.asarray(placement.samples, np.float64),
        parsed=placement.pairs or None,
        grounded=placement.tokens or None,
        failure=placement.failure,
        parse_note=parse_note(placement.parsed),
        # NaN-propagating: a NaN probability makes the scene's confidence no probability (harness: None).
        confidence=float(np.min([ref.probability for ref in placement.references])) if placement.references else None,
        probabilities=tuple(tuple(float(p) for p in ref.probabilities) for ref in placement.references) or None,
        decision=placement.decision if placement.references else None,
    )


@dataclasses.dataclass
class PolicyMethod:
    """A `Method` around a PlacementPolicy."""

    name: str
    policy: PlacementPolicy
    backbone_spec: str
    adapters_file: Path | None

    def run(self, scenes: Sequence[SceneRecord], key: jax.Array) -> list[MethodOutput]:
        placements = self.policy.place_many([scene_input(s) for s in scenes], key, progress=len(scenes) > 64)
        return [output_of(p) for p in placements]

    def describe(self) -> dict[str, Any]:
        return describe_policy(self.policy, self.name, self.backbone_spec, self.adapters_file)


def describe_policy(
    policy: PlacementPolicy, name: str, backbone_spec: str, adapters_file: Path | None
) -> dict[str, Any]:
    """JSON-able record of everything that decides the policy's placements."""
    from ocplace.models.parsing import default_config as parsing_config
    from ocplace.paths import llm_cache

    parser_name = getattr(policy.parser, "name", type(policy.parser).__name__)
    parsing = dataclasses.asdict(parsing_config())
    adapters = None
    if adapters_file is not None:
        from ocplace.models.trained_adapters import load_adapters

        trained = load_adapters(adapters_file)
        adapters = {
            "path": str(adapters_file),
            "sha256": hashlib.sha256(Path(adapters_file).read_bytes()).hexdigest(),
            "steps": trained.steps,
            "features_key": trained.features_key,
        }
    described: dict[str, Any] = serial.to_dict(
        {
            "method": name,
            "backbone": {"spec": backbone_spec, "fingerprint": policy.backbone.fingerprint},
            "adapters": adapters,
            "grounding": {
                "adapter_config": dataclasses.asdict(policy.grounding.config),
                "logit_scale": float(policy.grounding.logit_scale),
                "zero_shot": adapters is None,
            },
            "prompt": dataclasses.asdict(policy.prompt),
            "parser": {
                "name": parser_name,
                "config": parsing,
                "cache": str(llm_cache(parsing["llm"]["cache_subdir"])) if parser_name == "llm" else None,
            },
            "sampler": dataclasses.asdict(policy.sampler),
            "threshold": policy.threshold,
            "policy": {
                "crop_size": policy.crop_size,
                "min_boxes": policy.min_boxes,
                "max_tuples": policy.max_tuples,
                "detector": dataclasses.asdict(policy.detector),
                "decision": dataclasses.asdict(policy.decision),
                "boxes": "dataset (from segmentation)",
                "aabbs": "dataset (simulator AABBs of boxed objects)",
            },
        },
    )
    return described


def policy_of(ctx: LoadContext, adapters_file: Path | None, row: str) -> PlacementPolicy:
    """The placement policy of the row `row` on `ctx`'s backbone, parser, sample count and inference settings, with
    these adapters (None: zero-shot). Its backbone reads the test features that another evaluation on it encoded
    (models/shared_features.py)."""
    from ocplace.models.backbone import load_backbone
    from ocplace.models.policy import PlacementPolicy
    from ocplace.models.shared_features import SharedFeatures

    return PlacementPolicy.from_run(
        SharedFeatures(load_backbone(ctx.backbone)), adapters_file, parser=ctx.parser, **policy_settings(ctx, row)
    )


def policy_settings(ctx: LoadContext, row: str) -> dict[str, Any]:
    """The `PlacementPolicy` fields an evaluation sets: its sample count and threshold, and the inference settings of
    `ctx` (those of the row `row`, its package's `INFERENCE`, when `ctx` has none)."""
    from ocplace.methods.registry import inference_defaults
    from ocplace.models.placement.sampler import SamplerConfig

    inference = ctx.inference if ctx.inference is not None else inference_defaults().get(row)
    fields = {} if inference is None else inference.policy_fields()
    return {"sampler": SamplerConfig(num_samples=ctx.num_samples), "threshold": ctx.threshold, **fields}


def trained_run_weights(run_dir: Path | None, what: str, method: str) -> Path:
    """The weights file of `method`'s finished run in `run_dir`; TrainingError when there is none."""
    from ocplace.errors import TrainingError
    from ocplace.paths import trained_weights

    how_to_train = f"train the {method!r} method first"
    if run_dir is None:
        raise TrainingError(f"no trained {what}: no run directory; {how_to_train}")
    return trained_weights(run_dir, what, how_to_train)
