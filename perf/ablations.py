"""Training time of the two ablations' recipes, measured on synthetic inputs of the real shapes.

A step costs the same whatever the pixels or features hold, so the recipe's time is estimated
as compile + steps x (measured seconds per step); the one-off input caches (crops for
no_pretrain, sentence tokens for no_llm; the visual features are Ours' shared cache) are not
included. Usage:
    python perf/ablations.py --experiment default [--steps 40] [--dim 256] [--out report.json]
`--steps` is how many steps are timed after compilation (the estimate extrapolates to the recipe).
"""

from __future__ import annotations

import argparse
import json
import os
import time

import jax
import jax.numpy as jnp
import numpy as np

from ocplace import serial
from ocplace.methods.no_llm.recipe import NoLlmRecipe
from ocplace.methods.no_pretrain.recipe import NoPretrainRecipe
from ocplace.train import optim


def time_no_llm(experiment: str, dim: int, steps: int, num_scenes: int) -> dict:
    from ocplace import configs
    from ocplace.methods.no_llm import train as no_llm

    config = configs.get(experiment).recipe_as("no_llm", NoLlmRecipe)
    schedule = config.schedule
    rng = np.random.default_rng(0)
    arrays = {
        "visual": rng.normal(size=(num_scenes, 6, dim)).astype(np.float32),
        "visual_mask": np.ones((num_scenes, 6), bool),
        "sentence": rng.normal(size=(num_scenes, dim)).astype(np.float32),
        "targets": rng.integers(6, size=(num_scenes, 2)).astype(np.int32),
        "target_mask": np.ones((num_scenes, 2), bool),
        "relations": rng.integers(8, size=(num_scenes, 2)).astype(np.int32),
    }
    model_config = config.model_config(dim)
    params = no_llm.init_params(model_config, jax.random.key(0))
    state = (params, optim.make(schedule).init(params))
    data = jax.device_put(arrays)

    def run(count, start):
        nonlocal state
        indices = no_llm.batch_indices(num_scenes, 0, start, count, schedule.batch_size)
        with Timer() as timer:
            state, losses = no_llm.train_chunk(model_config, config, 100.0, state, data, jnp.asarray(indices))
            jax.block_until_ready(losses)
        return timer

    first = run(steps, 0)
    timed = run(steps, steps)
    return {
        "method": "no_llm",
        "experiment": experiment,
        "dim": dim,
        "batch_size": schedule.batch_size,
        "recipe_steps": schedule.steps,
        **report_times(first, timed, steps, schedule.steps),
    }


def time_no_pretrain(experiment: str, steps: int, num_scenes: int) -> dict:
    from ocplace import configs
    from ocplace.methods.no_pretrain import model as no_pretrain
    from ocplace.methods.no_pretrain import train as train_no_pretrain
    from ocplace.models.offline_backbone import split_trainable

    recipe = configs.get(experiment).recipe_as("no_pretrain", NoPretrainRecipe)
    model, schedule = recipe.model, recipe.schedule
    size = model.backbone.image_size
    rng = np.random.default_rng(0)
    arrays = {
        "pixels": rng.integers(256, size=(num_scenes, 6, size, size, 3), dtype=np.uint8),
        "visual_mask": np.ones((num_scenes, 6), bool),
        "sentences": rng.normal(size=(num_scenes, 2, model.backbone.text_dim)).astype(np.float32),
        "text_mask": np.ones((num_scenes, 2), bool),
        "targets": rng.integers(6, size=(num_scenes, 2)).astype(np.int32),
    }
    params = no_pretrain.init_params(model, jax.random.key(0))
    trainable, frozen = split_trainable(no_pretrain.trainable_mask(model, params), params)
    state = (trainable, optim.make(schedule).init(trainable))

    def step(index):
        nonlocal state
        rows = train_no_pretrain.batch_indices(num_scenes, 0, index, 1, schedule.batch_size)[0]
        batch = {name: jnp.asarray(array[rows]) for name, array in arrays.items()}
        codes = jnp.asarray(train_no_pretrain.step_codes(recipe, 0, index))
        state, loss = train_no_pretrain.train_step(model, schedule, state, frozen, batch, codes)
        return loss

    with Timer() as first:
        jax.block_until_ready(step(0))
    with Timer() as timed:
        for index in range(1, steps + 1):
            loss = step(index)
        jax.block_until_ready(loss)
    parameters = sum(int(leaf.size) for leaf in jax.tree_util.tree_leaves(params))
    return {
        "method": "no_pretrain",
        "experiment": experiment,
        "model": serial.to_dict(model),
        "parameters": parameters,
        "batch_scenes": schedule.batch_size,
        "recipe_steps": schedule.steps,
        **report_times(first, timed, steps, schedule.steps),
    }


class Timer:
    """Wall and process CPU seconds of a block (CPU time is less sensitive to other jobs on the machine)."""

    def __enter__(self):
        self.wall, self.cpu = time.perf_counter(), time.process_time()
        return self

    def __exit__(self, *exc):
        self.wall, self.cpu = time.perf_counter() - self.wall, time.process_time() - self.cpu


def report_times(first: Timer, timed: Timer, steps: int, recipe_steps: int) -> dict:
    return {
        "first_call_wall_s": round(first.wall, 2),
        "first_call_cpu_s": round(first.cpu, 2),
        "step_wall_ms": round(1e3 * timed.wall / steps, 3),
        "step_cpu_ms": round(1e3 * timed.cpu / steps, 3),
        "estimated_train_wall_s": round(first.wall + timed.wall / steps * recipe_steps, 1),
        "estimated_train_cpu_s": round(first.cpu + timed.cpu / steps * recipe_steps, 1),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--experiment", default="default", choices=("smoke", "demo", "default"))
    parser.add_argument("--steps", type=int, default=40, help="steps timed after compilation")
    parser.add_argument("--dim", type=int, default=256, help="backbone width D for no_llm (offline: 256)")
    parser.add_argument("--scenes", type=int, default=200, help="synthetic training scenes held in memory")
    parser.add_argument("--out", help="write the report here as JSON")
    args = parser.parse_args()
    report = {
        "cpus": len(os.sched_getaffinity(0)),
        "load_average": os.getloadavg(),
        "results": [
            time_no_llm(args.experiment, args.dim, args.steps, args.scenes),
            time_no_pretrain(args.experiment, args.steps, args.scenes),
        ],
    }
    text = json.dumps(report, indent=2)
    print(text)
    if args.out:
        with open(args.out, "w") as handle:
            handle.write(text + "\n")


if __name__ == "__main__":
    main()
