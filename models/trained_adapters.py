"""The adapters file a training run ends with, and its loader.

`RUN/weights.safetensors` (`paths.WEIGHTS_FILE`) holds the adapter weights with, in its metadata, what the policy needs
to use them: the adapter config, the logit scale, the fingerprint of the backbone whose features
they were trained on and the prompt the reference phrases were written with. Written and read
through `models.weights_file`, so a damaged file is a `WeightsError`, never silently wrong weights.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import jax

from ocplace import serial
from ocplace.errors import TrainingError
from ocplace.models.adapters import AdapterConfig, init_adapters
from ocplace.models.backbone import PromptConfig
from ocplace.models.grounding import GroundingModel
from ocplace.models.weights_file import (
    WEIGHTS_KINDS,
    expect_kind,
    flatten_state,
    load_weights,
    save_weights,
    unflatten_state,
)
from ocplace.paths import trained_weights


@dataclasses.dataclass(frozen=True)
class TrainedAdapters:
    """The result of a run, as the policy needs it."""

    model: GroundingModel
    backbone_fingerprint: str  # features (and so the adapters) belong to this backbone
    prompt: PromptConfig  # how reference phrases were turned into text during featurization
    features_key: str
    steps: int
    source: Path  # the run directory or adapters file they were loaded from, as given


def save_adapters(
    path: Path,
    params,
    config: AdapterConfig,
    logit_scale: float,
    *,
    backbone_fingerprint: str,
    prompt: PromptConfig,
    features_key: str,
    steps: int,
    train_config_json: str,
) -> None:
    metadata = {
        "adapter_config": json.dumps(dataclasses.asdict(config)),
        "logit_scale": repr(logit_scale),
        "backbone_fingerprint": backbone_fingerprint,
        "prompt": serial.to_json(prompt),
        "features_key": features_key,
        "steps": str(steps),
        "train_config": train_config_json,
    }
    save_weights(path, flatten_state(params), metadata)


# What `save_adapters` records, and `load_adapters` needs.
ADAPTER_METADATA = ("adapter_config", "logit_scale", "backbone_fingerprint", "prompt", "features_key", "steps")


def load_adapters(source) -> TrainedAdapters:
    """Trained adapters from a run directory or its weights file, verified."""
    source = Path(source)
    how_to_train = "train them with `ocplace train`"
    path = trained_weights(source, "adapters", how_to_train) if source.is_dir() else source
    if not path.exists():
        raise TrainingError(f"no trained adapters at {path}; {how_to_train}")
    rebuild = (
        f"delete {path.parent} and train it again (`ocplace train ... --out {path.parent}`, or `ocplace reproduce`, "
        "which retrains missing runs)"
        if source.is_dir()  # a folder the user named: never advise deleting one they did not
        else f"pass a run directory (OUT/runs/ours/fraction-1.00) or the adapters file a run wrote instead of {path}"
    )
    arrays, metadata = load_weights(path, rebuild)
    wanted, example = WEIGHTS_KINDS["adapter_config"], "OUT/runs/ours/fraction-1.00"
    expect_kind(path, metadata, list(ADAPTER_METADATA), wanted, example)
    config = AdapterConfig(**json.loads(metadata["adapter_config"]))
    template = jax.eval_shape(lambda: init_adapters(config, jax.random.key(0)))
    params = unflatten_state(arrays, template)
    model = GroundingModel(config, params, float(metadata["logit_scale"]))
    return TrainedAdapters(
        model,
        metadata["backbone_fingerprint"],
        serial.from_json(PromptConfig, metadata["prompt"]),
        metadata["features_key"],
        int(metadata["steps"]),
        source,
    )
