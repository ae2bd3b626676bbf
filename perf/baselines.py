"""CPU cost of the two baselines, projected onto their recipes (random weights and data, no dataset).

Measures: (1) Raw Image Grids featurisation, seconds per scene (cutting 48 cells out of a 640 x 480
frame and encoding them with a default-size offline backbone); (2) its training step time, and the
recipe's projected training time; (3) CLIPort-Place's training step time and projected training
time; (4) CLIPort-Place's inference, seconds per scene at batch 8.
Usage: `python perf/baselines.py [--experiment default] [--grid-steps 2000] [--cliport-steps 6]`.
"""

from __future__ import annotations

import argparse
import json
import os
import time

import jax
import jax.numpy as jnp
import numpy as np

from ocplace import configs
from ocplace.methods.cliport import model as cliport
from ocplace.methods.cliport import train as train_cliport
from ocplace.methods.cliport.recipe import CliportRecipe
from ocplace.methods.grids import model as grids
from ocplace.methods.grids import train as train_grids
from ocplace.methods.grids.recipe import GridsRecipe
from ocplace.models import offline_backbone as ob
from ocplace.models import offline_config
from ocplace.sim.camera import Camera
from ocplace.train import optim

CPU_SECONDS: dict[str, float] = {}  # process CPU time (all threads) per measurement, beside the wall clock


def timed(fn, name: str = "") -> float:
    """Wall seconds of `fn()`; its CPU seconds go to CPU_SECONDS[name] (robust to a busy machine)."""
    start, cpu = time.perf_counter(), time.process_time()
    jax.block_until_ready(fn())
    CPU_SECONDS[name] = time.process_time() - cpu
    return time.perf_counter() - start


def grid_featurize_seconds(backbone, config: grids.GridConfig, scenes: int) -> float:
    rgb = np.random.default_rng(0).integers(0, 256, (480, 640, 3), dtype=np.uint8)
    backbone.encode_images(grids.cell_crops(rgb, Camera(), config))  # compile
    return (
        timed(
            lambda: [backbone.encode_images(grids.cell_crops(rgb, Camera(), config)) for _ in range(scenes)],
            "grids_featurize",
        )
        / scenes
    )


def grid_step_seconds(recipe: train_grids.GridsRecipe, dim: int, steps: int) -> float:
    config, schedule = recipe.grid, recipe.schedule
    rng = np.random.default_rng(0)
    data = (
        rng.normal(size=(200, config.num_cells, dim)).astype(np.float32),
        rng.normal(size=(200, 2, dim)).astype(np.float32),
        np.ones((200, 2), bool),
        rng.integers(0, config.num_cells, 200).astype(np.int32),
    )
    params = grids.init_grids(config, dim, jax.random.key(0))

    def run():
        fresh = jax.tree_util.tree_map(jnp.copy, params)  # the step donates its state
        state = (fresh, optim.make(schedule).init(fresh))
        indices = jnp.asarray(rng.integers(0, 200, (steps, schedule.batch_size)), jnp.int32)
        return train_grids.train_chunk(config, schedule, 30.0, state, data, indices)[1]

    run()  # compile
    return timed(run, "grids_steps") / steps


def cliport_seconds(recipe: train_cliport.CliportRecipe, dim: int, steps: int) -> tuple[float, float]:
    config, schedule = recipe.network, recipe.schedule
    rng = np.random.default_rng(0)
    count = 32
    data: dict[str, np.ndarray] = {
        "rgb": rng.integers(0, 256, (count, config.height, config.width, 3), dtype=np.uint8),
        "height": rng.uniform(0, 0.2, (count, config.height, config.width)).astype(np.float16),
        "text": rng.normal(size=(count, dim)).astype(np.float32),
        "targets": rng.integers(0, config.num_pixels, (count, 4)).astype(np.int32),
    }
    mask = jnp.ones((config.height, config.width), bool)
    params = cliport.init_network(config, dim, jax.random.key(0))

    def run():
        fresh = jax.tree_util.tree_map(jnp.copy, params)  # the step donates its state
        state = (fresh, optim.make(schedule).init(fresh))
        indices = jnp.asarray(rng.integers(0, count, (steps, schedule.batch_size)), jnp.int32)
        keys = jax.random.split(jax.random.key(0), steps)
        return train_cliport.train_chunk(config, schedule, state, data, mask, indices, keys)[1]

    run()  # compile
    step = timed(run, "cliport_steps") / steps
    batch = {name: data[name][:8] for name in ("rgb", "height", "text")}

    def infer():
        return cliport.jit_distribution(config, params, batch["rgb"], batch["height"], batch["text"], mask)

    infer()
    return step, timed(infer, "cliport_infer_batch_8") / 8


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--experiment", default="default", choices=sorted(configs.EXPERIMENTS))
    parser.add_argument("--grid-steps", type=int, default=2000)
    parser.add_argument("--cliport-steps", type=int, default=6)
    parser.add_argument("--scenes", type=int, default=4, help="scenes for the featurisation timing")
    args = parser.parse_args()

    config = offline_config.default_config() if args.experiment == "default" else offline_config.smoke_config()
    backbone = ob.OfflineBackbone(config, ob.init_params(config, jax.random.key(0)))
    experiment = configs.get(args.experiment)
    grid_recipe = experiment.recipe_as("grids", GridsRecipe)
    cliport_recipe = experiment.recipe_as("cliport", CliportRecipe)
    featurize = grid_featurize_seconds(backbone, grid_recipe.grid, args.scenes)
    grid_step = grid_step_seconds(grid_recipe, backbone.dim, args.grid_steps)
    cliport_step, cliport_infer = cliport_seconds(cliport_recipe, backbone.dim, args.cliport_steps)
    print(
        json.dumps(
            {
                "experiment": args.experiment,
                "backbone_dim": backbone.dim,
                "cpus": len(os.sched_getaffinity(0)),
                "grids_featurize_s_per_scene": round(featurize, 4),
                "grids_step_ms": round(1e3 * grid_step, 4),
                "grids_recipe_train_s": round(grid_step * grid_recipe.schedule.steps, 1),
                "cliport_step_s": round(cliport_step, 4),
                "cliport_recipe_train_s": round(cliport_step * cliport_recipe.schedule.steps, 1),
                "cliport_infer_s_per_scene": round(cliport_infer, 4),
                "cpu_seconds": {name: round(value, 3) for name, value in CPU_SECONDS.items()},
                "counts": {
                    "grids_featurize_scenes": args.scenes,
                    "grids_steps": args.grid_steps,
                    "cliport_steps": args.cliport_steps,
                    "cliport_infer_scenes": 8,
                },
            },
            indent=1,
        )
    )


if __name__ == "__main__":
    main()
