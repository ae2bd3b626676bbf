"""The resumable training loop every training in ocplace runs: one `Run` describes it, `run` runs it.

Run directory:
    run.json (`paths.RUN_FILE`)           the run's metadata; a rerun with other metadata is refused
    metrics.jsonl                         one record per `log_every` steps and at the end
    checkpoints/step_*.safetensors        the state (the newest `keep_checkpoints`)
    weights.safetensors (`paths.WEIGHTS_FILE`) or the run's own `artefact`: written last, once every step is done

A run resumes from its newest checkpoint (`metrics.jsonl` cut back to it). Each `chunk` call must
be a pure function of the state and its step range (keys and example order drawn from the seed and
the step), so a resumed run ends with exactly the state of an uninterrupted one.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ocplace.errors import TrainingError
from ocplace.paths import WEIGHTS_FILE
from ocplace.train import checkpoints
from ocplace.train.metrics import MetricsLog

log = logging.getLogger(__name__)

METRICS_FILE = "metrics.jsonl"


@dataclasses.dataclass(frozen=True)
class Run:
    """A training run: where it lives, its cadences, and the pieces only it knows.

    `chunk(state, start, count) -> (state, losses)` takes steps `start ... start + count - 1`;
    `losses` has the steps on its last axis `(..., count)`. `record(state, step, losses)` gives a
    metrics record's fields besides `step` and `elapsed_s`, from the losses of every step since the
    previous record `(..., steps)`. `save_artefact(path, state)` writes `artefact` atomically, after
    anything else it writes.
    """

    run_dir: Path
    run_meta: dict  # JSON: what makes this run this run
    steps: int
    chunk_steps: int  # steps per `chunk` call
    checkpoint_every: int  # a multiple of chunk_steps
    keep_checkpoints: int
    init_state: Callable[[], Any]  # the fresh state, also the template a checkpoint is restored into
    chunk: Callable[[Any, int, int], tuple[Any, Any]]
    record: Callable[[Any, int, np.ndarray], dict]
    save_artefact: Callable[[Path, Any], Any]
    log_every: int | None = None  # a multiple of chunk_steps; None: every chunk
    artefact: Path | None = None  # None: the run directory's WEIGHTS_FILE
    checkpoint_meta: dict[str, str] = dataclasses.field(default_factory=dict)
    desc: str = "train"

    @classmethod
    def on(cls, budget: Any, **fields: Any) -> Run:
        """A run on `budget`'s cadence (a recipe or a `Schedule`: its steps, chunk_steps, checkpoint_every and
        keep_checkpoints), with the other fields given."""
        return cls(**{name: getattr(budget, name) for name in _CADENCE}, **fields)

    @property
    def log_steps(self) -> int:
        return self.chunk_steps if self.log_every is None else self.log_every

    @property
    def artefact_path(self) -> Path:
        return Path(self.run_dir) / WEIGHTS_FILE if self.artefact is None else Path(self.artefact)

    def validate(self) -> None:
        if min(self.steps, self.chunk_steps, self.log_steps, self.checkpoint_every, self.keep_checkpoints) < 1:
            raise TrainingError(f"{self.desc}: steps, cadences and keep_checkpoints must be positive")
        if self.log_steps % self.chunk_steps or self.checkpoint_every % self.chunk_steps:
            raise TrainingError(f"{self.desc}: log_every and checkpoint_every must be multiples of chunk_steps")


_CADENCE = ("steps", "chunk_steps", "checkpoint_every", "keep_checkpoints")


@dataclasses.dataclass(frozen=True)
class RunOutcome:
    state: Any
    saved: Any  # what `save_artefact` returned; None when stopped before the end


def run(
    spec: Run, progress: bool = True, callback: Callable[[dict], None] | None = None, stop_after: int | None = None
) -> RunOutcome:
    """Claims the run directory, resumes, trains to `spec.steps` and saves the artefact. A finished run (its last
    checkpoint and its artefact there) is the one "already done" of every training: returned with its final state,
    nothing written (`saved` None).

    `callback(record)` runs after each metrics record (and its checkpoint), e.g. to stop by raising;
    `stop_after` returns after that many more steps without saving the artefact (to test resuming).
    """
    from ocplace.runtime.progress import progress_bar

    spec.validate()
    run_dir = Path(spec.run_dir)
    checkpoints.claim_run_dir(run_dir, spec.run_meta)
    state, start = resume(run_dir, spec.init_state())
    if start == spec.steps and spec.artefact_path.is_file():
        return RunOutcome(state, None)  # finished before: its artefact is kept as it is, never written again
    metrics = MetricsLog(run_dir / METRICS_FILE)
    metrics.truncate_after(start)
    last = spec.steps if stop_after is None else min(spec.steps, start + stop_after)
    pending, step, began = [], start, time.perf_counter()
    with progress_bar(total=spec.steps, initial=start, unit="step", desc=spec.desc, enabled=progress) as bar:
        while step < last:
            count = min(spec.chunk_steps, last - step)
            state, losses = spec.chunk(state, step, count)
            pending.append(losses)
            step += count
            record = None
            if step % spec.log_steps == 0 or step == spec.steps:
                record = {"step": step, **spec.record(state, step, _joined(pending))}
                record["elapsed_s"] = round(time.perf_counter() - began, 3)
                # Before the checkpoint: a crash between the two leaves a record the resume cuts back, not a gap.
                metrics.append(record)
                pending = []
                bar.set_postfix(loss=f"{record['loss']:.4f}")
            if step % spec.checkpoint_every == 0 or step == spec.steps:
                checkpoints.save_checkpoint(run_dir, step, state, spec.checkpoint_meta, spec.keep_checkpoints)
            bar.update(count)
            if record is not None and callback is not None:
                callback(record)
    saved = spec.save_artefact(spec.artefact_path, state) if step == spec.steps else None
    return RunOutcome(state, saved)


def resume(run_dir: Path, state) -> tuple[Any, int]:
    """`(state, step)` of the newest checkpoint, restored into `state`'s structure; `(state, 0)` without one."""
    saved = checkpoints.list_checkpoints(run_dir)
    if not saved:
        return state, 0
    state, start, _ = checkpoints.load_checkpoint(saved[-1], state)
    log.info("resuming %s from step %d", run_dir, start)
    return state, start


def mean_loss(losses: np.ndarray) -> float:
    return float(np.mean(losses))


def loss_and_learning_rate(schedule: Callable) -> Callable[[Any, int, np.ndarray], dict]:
    """The usual `record`: the mean loss since the last record and the learning rate at `step`."""

    def record(state, step: int, losses: np.ndarray) -> dict:
        return {"loss": mean_loss(losses), "learning_rate": float(schedule(step))}

    return record


def _joined(pending: list) -> np.ndarray:
    """The losses of several chunks as one array, steps on the last axis."""
    arrays = [np.asarray(losses) for losses in pending]
    return arrays[0] if len(arrays) == 1 else np.concatenate(arrays, axis=-1)
