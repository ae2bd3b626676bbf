"""The run directory of the baselines (Raw Image Grids, CLIPort-Place), trained by `train.runner`.

    RUN/run.json              the run: method, recipe, fraction, seed, data keys, backbone fingerprint
    RUN/metrics.jsonl         per chunk of steps: step, loss (chunk mean), learning_rate, elapsed_s
    RUN/checkpoints/step_*.safetensors   params + optimiser state (the newest `keep` kept)
    RUN/weights.safetensors   the final parameters; its presence marks the run finished

Checkpoints and weights carry a content hash (`models.weights_file`), checked on load; a finished
run is read back by `models.baselines.trained_run.load_run`.

A rerun with the same directory and settings skips a finished run and resumes an interrupted one
from its newest checkpoint (`metrics.jsonl` is cut back to it); other settings are refused. Steps
are functions of (seed, step) alone, so a resumed run ends where an uninterrupted one would.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable
from pathlib import Path

import jax
import numpy as np

from ocplace.models import weights_file
from ocplace.models.backbone import Backbone
from ocplace.paths import WEIGHTS_FILE
from ocplace.train import checkpoints, optim, runner
from ocplace.train.schedule import Schedule


@dataclasses.dataclass(frozen=True)
class BaselineRun:
    """What a baseline's training reads beside its recipe: the backbone, the dataset, its run directory, the share
    of the training split and the seed; `experiment` names the experiment in the run's metadata only."""

    backbone: Backbone
    dataset_dir: Path
    out_dir: Path
    fraction: float = 1.0
    seed: int = 0
    experiment: str = "default"
    progress: bool = True


def train(
    run_dir: Path,
    run_meta: dict,
    init_params: Callable,
    chunk: Callable,
    schedule: Schedule,
    progress: bool = True,
    desc: str = "train",
) -> None:
    """Runs `chunk(state, start_step, num_steps) -> (state, losses)` up to `schedule.steps`, then saves the weights.

    `init_params()` gives the fresh parameters; with their fresh Adam state, `(params, opt_state)` is the
    template a checkpoint is restored into.
    """
    schedule.validate()
    run_dir = Path(run_dir)
    weights_meta = {"run": json.dumps(run_meta, sort_keys=True)}
    spec = runner.Run.on(
        schedule,
        run_dir=run_dir,
        run_meta=run_meta,
        init_state=lambda: _with_adam_state(init_params(), schedule),
        chunk=chunk,
        record=runner.loss_and_learning_rate(optim.learning_rates(schedule)),
        save_artefact=lambda _artefact, state: save_weights(run_dir, state[0], weights_meta),
        desc=desc,
    )
    runner.run(spec, progress)


def _with_adam_state(params, schedule: Schedule) -> tuple:
    return params, optim.make(schedule).init(params)


def save_weights(run_dir: Path, params, metadata: dict[str, str]) -> Path:
    return weights_file.save_weights(Path(run_dir) / WEIGHTS_FILE, checkpoints.flatten_state(params), metadata)


def step_keys(seed: int, start: int, count: int):
    """`(count,)` keys of steps `start ...`: `fold_in(key(seed), step)`, the same whether resumed or not."""
    return jax.vmap(lambda s: jax.random.fold_in(jax.random.key(seed), s))(np.arange(start, start + count))
