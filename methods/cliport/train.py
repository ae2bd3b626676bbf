"""Training CLIPort-Place: cached downsampled RGB-D, sentence embeddings and feasible target pixels.

Per training scene the cache holds the image at the network's resolution, the backbone's
embedding of the whole instruction, and `num_targets` pixels drawn uniformly from the oracle's
feasible region (`sim.metric.feasible_grid` on the scene's ground-truth problem, 5 mm grid),
projected through the scene's camera. Each step picks one of them per example (keys folded from
the seed and the step), so over the epochs the network sees the whole region, not one point.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import optax

from ocplace import serial
from ocplace.methods.cliport import model as cliport
from ocplace.methods.cliport.recipe import CliportConfig, CliportRecipe
from ocplace.models.backbone import Backbone
from ocplace.models.baselines.common import top_down_camera
from ocplace.paths import atomic_path, baselines_cache
from ocplace.sim import metric
from ocplace.sim.dataset.job import listed_scenes
from ocplace.train import baseline_runs, optim
from ocplace.train.baseline_runs import BaselineRun, Schedule
from ocplace.train.batches import batch_indices, subset_indices

CACHE_FORMAT = "ocplace-cliport-data-v1"
DATA_ARRAYS = ("rgb", "height", "text", "targets")


def target_pixels(record, num_targets: int, seed: int, config: CliportConfig) -> np.ndarray:
    """`(num_targets,)` flat pixels of points drawn from the scene's feasible region (ground truth)."""
    feasible = metric.feasible_grid(record.problem())
    rng = np.random.default_rng([seed, record.index])
    points = metric.sample_oracle_placements(feasible, num_targets, rng, scene=record.id)
    camera = top_down_camera(record)
    return cliport.pixel_to_flat(cliport.table_to_pixel(points, camera, config), config)


def scene_arrays(
    dataset_dir: Path, split: str, recipe: CliportRecipe, backbone: Backbone, progress: bool
) -> tuple[dict[str, np.ndarray], list[str]]:
    from ocplace.runtime.progress import progress_bar

    config = recipe.network
    rgbs, heights, targets, instructions, ids = [], [], [], [], []
    for scene in progress_bar(listed_scenes(dataset_dir, split), desc="cliport data", unit="scene", enabled=progress):
        record = scene.read()
        rgb, height = cliport.prepare_image(record.rgb, record.depth, top_down_camera(record), config)
        rgbs.append(rgb)
        heights.append(height)
        targets.append(target_pixels(record, recipe.num_targets, 0, config))
        instructions.append(record.instruction)
        ids.append(record.id)
    arrays = {
        "rgb": np.stack(rgbs),
        "height": np.stack(heights),
        "text": backbone.encode_texts(instructions).astype(np.float32),
        "targets": np.stack(targets),
    }
    return arrays, ids


def training_data(
    dataset_dir: Path, backbone: Backbone, recipe: CliportRecipe, split: str = "train", progress: bool = True
) -> tuple[dict[str, np.ndarray], str]:
    """`(arrays, key)` of the split, from the cache (built on first use); arrays as in DATA_ARRAYS."""
    from safetensors import safe_open
    from safetensors.numpy import load_file, save_file

    from ocplace.sim.dataset.identity import dataset_hash

    digest = dataset_hash(dataset_dir, split)
    key = hashlib.sha256(
        json.dumps(
            [CACHE_FORMAT, digest, backbone.fingerprint, serial.to_json(recipe.network), recipe.num_targets]
        ).encode()
    ).hexdigest()
    path = baselines_cache() / f"cliport-{digest[:16]}-{split}-{key[:16]}.safetensors"
    if path.is_file():
        with safe_open(str(path), framework="numpy") as handle:
            if (handle.metadata() or {}).get("key") == key:
                return load_file(str(path)), key
    arrays, ids = scene_arrays(Path(dataset_dir), split, recipe, backbone, progress)
    with atomic_path(path) as tmp:
        save_file(arrays, str(tmp), metadata={"key": key, "scenes": json.dumps(ids)})
    return arrays, key


def train_step(config: CliportConfig, schedule: Schedule, state, data, mask, indices, key):
    params, opt_state = state
    rgb, height, text, targets = (data[name][indices] for name in DATA_ARRAYS)
    choice = jax.random.randint(key, (indices.shape[0],), 0, targets.shape[-1])
    target = jnp.take_along_axis(targets, choice[:, None], axis=-1)[:, 0]
    loss, grads = jax.value_and_grad(cliport.pixel_loss, argnums=1)(config, params, rgb, height, text, mask, target)
    updates, opt_state = optim.make(schedule).update(grads, opt_state, params)
    return (optax.apply_updates(params, updates), opt_state), loss


jit_train_step = jax.jit(train_step, static_argnums=(0, 1), donate_argnums=2)


def train_chunk(config: CliportConfig, schedule: Schedule, state, data, mask, indices, keys):
    """`indices (num_steps, B)` and `keys (num_steps,)`: one jitted call per step; returns `(state, losses)`.

    Not a `lax.scan` like the adapters' loop: XLA:CPU runs convolutions inside a loop body with a
    slow generic kernel (measured 70 CPU-s per step instead of 0.8).
    """
    losses = []
    for step_indices, key in zip(indices, keys):
        state, loss = jit_train_step(config, schedule, state, data, mask, step_indices, key)
        losses.append(loss)
    return state, jnp.stack(losses)


def train_cliport(run: BaselineRun, recipe: CliportRecipe) -> None:
    """Trains CLIPort-Place into `run.out_dir`, resumed when interrupted (`baseline_runs.train`)."""
    backbone, dataset_dir, out_dir, fraction, seed = run.backbone, run.dataset_dir, run.out_dir, run.fraction, run.seed
    config = recipe.network
    arrays, data_key = training_data(Path(dataset_dir), backbone, recipe, progress=run.progress)
    num_scenes = len(arrays["rgb"])
    subset = subset_indices(num_scenes, fraction, 0)
    camera = top_down_camera(listed_scenes(dataset_dir, "train")[0].read())
    run_meta = {
        "method": "cliport",
        "scale": run.experiment,
        "fraction": fraction,
        "seed": seed,
        "network": serial.to_dict(config),
        "schedule": dataclasses.asdict(recipe.schedule),
        "num_targets": recipe.num_targets,
        "data_key": data_key,
        "dim": int(backbone.dim),
        "backbone_fingerprint": backbone.fingerprint,
        "train_scenes": len(subset),
        "camera": camera.to_json(),
    }

    def init_params():
        return cliport.init_network(config, backbone.dim, jax.random.key(seed))

    data = jax.device_put({name: arrays[name][subset] for name in DATA_ARRAYS})
    mask = jnp.asarray(cliport.table_mask(camera, config))

    def chunk(state, start, count):
        indices = batch_indices(len(subset), seed, start, count, recipe.schedule.batch_size)
        keys = baseline_runs.step_keys(seed, start, count)
        return train_chunk(config, recipe.schedule, state, data, mask, jnp.asarray(indices), keys)

    baseline_runs.train(out_dir, run_meta, init_params, chunk, recipe.schedule, run.progress, "cliport")
