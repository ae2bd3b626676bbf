"""Checkpoints (adapter weights + Adam state) and the final adapters file, as safetensors.

Both are written and read through `models.weights_file`: a content hash in the file, checked on
load, so a damaged, truncated or NaN file is a `WeightsError` rather than silently wrong weights.

A checkpoint stores every leaf of the `(params, opt_state)` pytree under its key path, so it is
restored into a freshly initialised state of the same structure, bit for bit.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import jax
import numpy as np

from ocplace.errors import TrainingError
from ocplace.models.adapters import AdapterConfig
from ocplace.models.backbone import PromptConfig
from ocplace.models.grounding import GroundingModel
from ocplace.models.weights_file import load_weights, save_weights
from ocplace.paths import write_text_atomic

ADAPTERS_FILE = "adapters.safetensors"
CHECKPOINT_DIR = "checkpoints"


def flatten_state(state) -> dict[str, np.ndarray]:
    return {jax.tree_util.keystr(path): np.array(leaf) for path, leaf in jax.tree_util.tree_leaves_with_path(state)}


def unflatten_state(arrays: dict[str, np.ndarray], template):
    """`template`'s structure filled with `arrays`; keys, shapes and dtypes must match exactly."""
    paths, treedef = jax.tree_util.tree_flatten_with_path(template)
    expected = {jax.tree_util.keystr(path): leaf for path, leaf in paths}
    mismatched = sorted(set(arrays) ^ set(expected)) + sorted(
        key
        for key, leaf in expected.items()
        if key in arrays and (arrays[key].shape != tuple(leaf.shape) or arrays[key].dtype != np.dtype(leaf.dtype))
    )
    if mismatched:
        raise TrainingError(
            f"checkpoint does not match the model ({', '.join(mismatched[:3])} ...); start a new "
            "run directory (--out) for a different configuration"
        )
    return jax.tree_util.tree_unflatten(treedef, [arrays[jax.tree_util.keystr(path)] for path, _ in paths])


def checkpoint_path(run_dir: Path, step: int) -> Path:
    return Path(run_dir) / CHECKPOINT_DIR / f"step_{step:09d}.safetensors"


def save_checkpoint(run_dir: Path, step: int, state, metadata: dict[str, str], keep: int) -> Path:
    """Writes the checkpoint of `step` atomically, with its content hash, and keeps only the newest `keep`."""
    path = save_weights(checkpoint_path(run_dir, step), flatten_state(state), {**metadata, "step": str(step)})
    for old in list_checkpoints(run_dir)[:-keep]:
        old.unlink()
    return path


def list_checkpoints(run_dir: Path) -> list[Path]:
    return sorted((Path(run_dir) / CHECKPOINT_DIR).glob("step_*.safetensors"))


def load_checkpoint(path: Path, template) -> tuple[object, int, dict[str, str]]:
    """`(state, step, metadata)` of a verified checkpoint, restored into `template`'s structure."""
    path = Path(path)
    arrays, metadata = load_weights(
        path,
        f"delete {path.name} to resume from the checkpoint before it (or from "
        f"the start), or delete {path.parent.parent} to start the run over",
    )
    return unflatten_state(arrays, template), int(metadata["step"]), metadata


@dataclasses.dataclass(frozen=True)
class TrainedAdapters:
    """The result of a run, as the policy needs it."""

    model: GroundingModel
    backbone_fingerprint: str  # features (and so the adapters) belong to this backbone
    prompt: PromptConfig  # how reference phrases were turned into text during featurization
    features_key: str
    steps: int


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
        "prompt": prompt.to_json(),
        "features_key": features_key,
        "steps": str(steps),
        "train_config": train_config_json,
    }
    save_weights(path, flatten_state(params), metadata)


def load_adapters(path) -> TrainedAdapters:
    """Trained adapters from a run directory or an `adapters.safetensors` file, verified."""
    from ocplace.models.adapters import init_adapters

    path = Path(path)
    if path.is_dir():
        path = path / ADAPTERS_FILE
    if not path.exists():
        raise TrainingError(f"no trained adapters at {path}; train them with `ocplace train`")
    arrays, metadata = load_weights(
        path,
        f"delete {path.parent} and train it again (`ocplace train ... --out "
        f"{path.parent}`, or `ocplace reproduce`, which retrains missing runs)",
    )
    config = AdapterConfig(**json.loads(metadata["adapter_config"]))
    template = jax.eval_shape(lambda: init_adapters(config, jax.random.key(0)))
    params = unflatten_state(arrays, template)
    model = GroundingModel(config, params, float(metadata["logit_scale"]))
    return TrainedAdapters(
        model,
        metadata["backbone_fingerprint"],
        PromptConfig.from_json(metadata["prompt"]),
        metadata["features_key"],
        int(metadata["steps"]),
    )


def claim_run_dir(run_dir: Path, run_meta: dict, filename: str) -> None:
    """Writes `run_meta` to `run_dir/filename`, or checks that an existing run directory holds this very run."""
    path = run_dir / filename
    if path.exists():
        existing = json.loads(path.read_text())
        if existing != run_meta:
            changed = sorted(k for k in run_meta if existing.get(k) != run_meta[k])
            raise TrainingError(
                f"{run_dir} holds another run ({', '.join(changed)} differ); pass a new --out "
                "directory, or delete the old run to start over"
            )
        return
    run_dir.mkdir(parents=True, exist_ok=True)
    write_text_atomic(path, json.dumps(run_meta, indent=2, sort_keys=True) + "\n")
