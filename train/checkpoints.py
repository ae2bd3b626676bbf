"""Checkpoints (model weights + optimiser state) of a training run, and its run directory.

Written and read through `models.weights_file`: a content hash in the file, checked on load, so a
damaged, truncated or NaN file is a `WeightsError` rather than silently wrong weights. The final
adapters file of a run is `models.trained_adapters`'s: the policy loads it without training code.

A checkpoint stores every leaf of the `(params, opt_state)` pytree under its key path, so it is
restored into a freshly initialised state of the same structure, bit for bit.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from ocplace.errors import TrainingError
from ocplace.models.weights_file import flatten_state, load_weights, save_weights, unflatten_state
from ocplace.paths import RUN_FILE, read_run_file, refuse_old_run, write_text_atomic

CHECKPOINT_DIR = "checkpoints"


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


def load_checkpoint(path: Path, template) -> tuple[Any, int, dict[str, str]]:
    """`(state, step, metadata)` of a verified checkpoint, restored into `template`'s structure."""
    path = Path(path)
    arrays, metadata = load_weights(
        path,
        f"delete {path.name} to resume from the checkpoint before it (or from "
        f"the start), or delete {path.parent.parent} to start the run over",
    )
    return unflatten_state(arrays, template), int(metadata["step"]), metadata


def claim_run_dir(run_dir: Path, run_meta: dict) -> None:
    """Writes `run_meta` to `run_dir/RUN_FILE`, or checks that an existing run directory holds this very run."""
    refuse_old_run(run_dir, "train again")
    path = run_dir / RUN_FILE
    if path.exists():
        existing = read_run_file(run_dir)
        if existing != run_meta:
            changed = sorted(k for k in run_meta if existing.get(k) != run_meta[k])
            raise TrainingError(
                f"{run_dir} holds another run ({', '.join(changed)} differ); pass a new --out "
                "directory, or delete the old run to start over"
            )
        return
    run_dir.mkdir(parents=True, exist_ok=True)
    write_text_atomic(path, json.dumps(run_meta, indent=2, sort_keys=True) + "\n")
