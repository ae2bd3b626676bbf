"""Training Raw Image Grids: cached cell features, then the adapters and positional MLP with Adam.

Cell features of the training split are encoded once per (dataset, backbone, grid) with the
feature cache of `models/features.py` (chunked, resumable, atomic): a scene's 48 cell crops play
the part of its object crops, its tuple texts ("to the left of the red bowl") of the phrases, and
the target is the cell holding the oracle's placement (`SceneRecord.oracle.placement`, the
deepest point of the feasible region), the same for every tuple. The workspace token the cache
appends after the crops is not used.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
from collections.abc import Iterator
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import optax

from ocplace import serial
from ocplace.methods.grids import model as grids
from ocplace.methods.grids.recipe import GridConfig, GridsRecipe
from ocplace.models import features as feature_cache
from ocplace.models.backbone import Backbone
from ocplace.models.baselines.common import top_down_camera
from ocplace.paths import baselines_cache
from ocplace.sim.dataset.job import listed_scenes, scene_dirs
from ocplace.sim.dataset.loader import letterbox
from ocplace.train import baseline_runs, optim
from ocplace.train.baseline_runs import BaselineRun, Schedule
from ocplace.train.batches import batch_indices, subset_indices
from ocplace.vocabulary import MAX_INSTRUCTION_TUPLES


def scene_examples(dataset_dir: Path, split: str, config: GridConfig) -> Iterator[feature_cache.SceneToFeaturize]:
    """The cache's scene examples: cells as crops, tuple texts, the oracle's cell as every tuple's target."""
    for scene in listed_scenes(dataset_dir, split):
        record = scene.read()
        texts = tuple(grids.tuple_text(t.reference_name, t.relation) for t in record.true_tuples())
        target = int(grids.cell_of(record.true_placement(), config))
        yield feature_cache.SceneToFeaturize(
            scene_id=record.id,
            crops=grids.cell_crops(record.rgb, top_down_camera(record), config),
            workspace=letterbox(record.rgb, config.crop_size),
            texts=texts,
            targets=np.full(len(texts), target, np.int32),
        )


def cell_features(
    dataset_dir: Path, backbone: Backbone, config: GridConfig, split: str = "train", progress: bool = True
) -> feature_cache.Features:
    """The split's cell features, from the cache (computed on first use)."""
    from ocplace.sim.dataset.identity import dataset_hash

    digest = dataset_hash(dataset_dir, split)
    grid_key = hashlib.sha256(serial.to_json(config).encode()).hexdigest()
    name = f"grids-{digest[:16]}-{split}-{backbone.fingerprint[:16]}-{grid_key[:8]}.safetensors"
    path = baselines_cache() / name
    featurize_config = feature_cache.FeaturizeConfig(
        max_objects=config.num_cells, max_tuples=MAX_INSTRUCTION_TUPLES, prompt=grids.PLAIN_PROMPT
    )
    feature_cache.featurize(
        scene_examples(dataset_dir, split, config),
        backbone,
        path,
        dataset_hash=f"{digest}|grids|{serial.to_json(config)}",
        config=featurize_config,
        total=len(scene_dirs(dataset_dir, split)),
        progress=progress,
    )
    return feature_cache.load_features(path, expected_fingerprint=backbone.fingerprint)


def training_arrays(features: feature_cache.Features, config: GridConfig) -> tuple[np.ndarray, ...]:
    """`(cells (S, C, D), text (S, L, D), text_mask (S, L), targets (S,))` from cached features."""
    return (features.visual[:, : config.num_cells], features.text, features.text_mask, features.targets[:, 0])


def train_step(config: GridConfig, schedule: Schedule, logit_scale: float, state, data, indices):
    params, opt_state = state
    batch = tuple(array[indices] for array in data)
    loss, grads = jax.value_and_grad(grids.grid_loss, argnums=1)(config, params, *batch, logit_scale)
    updates, opt_state = optim.make(schedule).update(grads, opt_state, params)
    return (optax.apply_updates(params, updates), opt_state), loss


@functools.partial(jax.jit, static_argnums=(0, 1, 2), donate_argnums=3)
def train_chunk(config: GridConfig, schedule: Schedule, logit_scale: float, state, data, indices):
    """`indices (num_steps, B)`: the steps fused with `lax.scan`; returns `(state, losses)`."""
    step = functools.partial(train_step, config, schedule, logit_scale)
    return jax.lax.scan(lambda carry, step_indices: step(carry, data, step_indices), state, indices)


def train_grids(run: BaselineRun, recipe: GridsRecipe) -> None:
    """Trains Raw Image Grids into `run.out_dir`, resumed when interrupted (`baseline_runs.train`)."""
    backbone, dataset_dir, out_dir, fraction, seed = run.backbone, run.dataset_dir, run.out_dir, run.fraction, run.seed
    features = cell_features(Path(dataset_dir), backbone, recipe.grid, progress=run.progress)
    subset = features.subset(subset_indices(features.num_scenes, fraction, 0))
    logit_scale = float(features.info.logit_scale)
    run_meta = {
        "method": "grids",
        "scale": run.experiment,
        "fraction": fraction,
        "seed": seed,
        "grid": serial.to_dict(recipe.grid),
        "schedule": dataclasses.asdict(recipe.schedule),
        "features_key": features.info.key,
        "backbone_fingerprint": backbone.fingerprint,
        "logit_scale": logit_scale,
        "train_scenes": subset.num_scenes,
    }

    def init_params():
        return grids.init_grids(recipe.grid, features.dim, jax.random.key(seed))

    data = jax.device_put(training_arrays(subset, recipe.grid))

    def chunk(state, start, count):
        indices = batch_indices(subset.num_scenes, seed, start, count, recipe.schedule.batch_size)
        return train_chunk(recipe.grid, recipe.schedule, logit_scale, state, data, jnp.asarray(indices))

    baseline_runs.train(out_dir, run_meta, init_params, chunk, recipe.schedule, run.progress, "grids")
