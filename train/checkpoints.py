"""Checkpoints (adapter weights + Adam state) and the final adapters file, as safetensors.

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
from ocplace.paths import atomic_path, write_text_atomic

ADAPTERS_FILE = "adapters.safetensors"
CHECKPOINT_DIR = "checkpoints"


def flatten_state(state) -> dict[str, np.ndarray]:
    return {jax.tree_util.keystr(path): np.array(leaf)
            for path, leaf in jax.tree_util.tree_leaves_with_path(state)}


def unflatten_state(arrays: dict[str, np.ndarray], template):
    """`template`'s structure filled with `arrays`; keys, shapes and dtypes must match exactly."""
    paths, treedef = jax.tree_util.tree_flatten_with_path(template)
    expected = {jax.tree_util.keystr(path): leaf for path, leaf in paths}
    mismatched = sorted(set(arrays) ^ set(expected)) + sorted(
        key for key, leaf in expected.items() if key in arrays and
        (arrays[key].shape != tuple(leaf.shape) or arrays[key].dtype != np.dtype(leaf.dtype)))
    if mismatched:
        raise TrainingError(f"checkpoint does not match the model ({', '.join(mismatched[:3])} ...); start a new "
                            "run directory (--out) for a different configuration")
    return jax.tree_util.tree_unflatten(treedef, [arrays[jax.tree_util.keystr(path)] for path, _ in paths])


def checkpoint_path(run_dir: Path, step: int) -> Path:
    return Path(run_dir) / CHECKPOINT_DIR / f"step_{step:09d}.safetensors"


def save_checkpoint(run_dir: Path, step: int, state, metadata: dict[str, str], keep: int) -> Path:
    """Writes the checkpoint of `step` atomically and keeps only the newest `keep`."""
    from safetensors.numpy import save_file

    path = checkpoint_path(run_dir, step)
    with atomic_path(path) as tmp:
        save_file(flatten_state(state), str(tmp), metadata={**metadata, "step": str(step)})
    for old in list_checkpoints(run_dir)[:-keep]:
        old.unlink()
    return path


def list_checkpoints(run_dir: Path) -> list[Path]:
    return sorted((Path(run_dir) / CHECKPOINT_DIR).glob("step_*.safetensors"))


def load_checkpoint(path: Path, template) -> tuple[object, int, dict[str, str]]:
    """`(state, step, metadata)` of a checkpoint, restored into `template`'s structure."""
    from safetensors import safe_open
    from safetensors.numpy import load_file

    with safe_open(str(path), framework="numpy") as handle:
        metadata = handle.metadata()
    return unflatten_state(load_file(str(path)), template), int(metadata["step"]), metadata


@dataclasses.dataclass(frozen=True)
class TrainedAdapters:
    """The result of a run, as the policy needs it."""

    model: GroundingModel
    backbone_fingerprint: str  # features (and so the adapters) belong to this backbone
    prompt: PromptConfig  # how reference phrases were turned into text during featurization
    features_key: str
    steps: int


def save_adapters(path: Path, params, config: AdapterConfig, logit_scale: float, *, backbone_fingerprint: str,
                  prompt: PromptConfig, features_key: str, steps: int, train_config_json: str) -> None:
    from safetensors.numpy import save_file

    metadata = {"adapter_config": json.dumps(dataclasses.asdict(config)), "logit_scale": repr(logit_scale),
                "backbone_fingerprint": backbone_fingerprint, "prompt": prompt.to_json(),
                "features_key": features_key, "steps": str(steps), "train_config": train_config_json}
    with atomic_path(path) as tmp:
        save_file(flatten_state(params), str(tmp), metadata=metadata)


def load_adapters(path) -> TrainedAdapters:
    """Trained adapters from a run directory or an `adapters.safetensors` file."""
    from safetensors import safe_open
    from safetensors.numpy import load_file

    from ocplace.models.adapters import init_adapters

    path = Path(path)
    if path.is_dir():
        path = path / ADAPTERS_FILE
    if not path.exists():
        raise TrainingError(f"no trained adapters at {path}; train them with `ocplace train`")
    with safe_open(str(path), framework="numpy") as handle:
        metadata = handle.metadata()
    config = AdapterConfig(**json.loads(metadata["adapter_config"]))
    template = jax.eval_shape(lambda: init_adapters(config, jax.random.key(0)))
    params = unflatten_state(load_file(str(path)), template)
    model = GroundingModel(config, params, float(metadata["logit_scale"]))
    return TrainedAdapters(model, metadata["backbone_fingerprint"], PromptConfig.from_json(metadata["prompt"]),
                           metadata["features_key"], int(metadata["steps"]))


def claim_run_dir(run_dir: Path, run_meta: dict, filename: str) -> None:
    """Writes `run_meta` to `run_dir/filename`, or checks that an existing run directory holds this very run."""
    path = run_dir / filename
    if path.exists():
        existing = json.loads(path.read_text())
        if existing != run_meta:
            changed = sorted(k for k in run_meta if existing.get(k) != run_meta[k])
            raise TrainingError(f"{run_dir} holds another run ({', '.join(changed)} differ); pass a new --out "
                                "directory, or delete the old run to start over")
        return
    run_dir.mkdir(parents=True, exist_ok=True)
    write_text_atomic(path, json.dumps(run_meta, indent=2, sort_keys=True) + "\n")
