"""How a method of Table I trains and loads: one contract for every row.

A method is registered as a `MethodSpec`: how to train it (if it learns anything) and how to load a
trained run into an `ocplace.eval.api.Method`, which the harness scores. Training takes a
`TrainContext` holding the method's own recipe type, and returns the run directory.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any, Generic, Protocol, TypeVar

from ocplace import serial
from ocplace.errors import EvaluationError
from ocplace.eval.api import Method
from ocplace.models.inference_settings import InferenceSettings


class Recipe(Protocol):
    """What every row's recipe offers (a row's `RECIPE` type): `validate` raises with what cannot train."""

    def validate(self) -> None: ...


RecipeT = TypeVar("RecipeT")


@dataclasses.dataclass(frozen=True)
class TrainContext(Generic[RecipeT]):
    """Everything a method's training needs; `out_dir` is its run directory (resumable)."""

    dataset_dir: Path
    backbone: str  # backbone spec, e.g. "offline" or "clip:/path"
    out_dir: Path
    recipe: RecipeT  # the method's own training config (`Experiment.recipe(name)`); fraction and seed apart
    fraction: float = 1.0  # share of the training split (seeded subsets, nested)
    seed: int = 0
    experiment: str = "default"  # the experiment's name, recorded in run metadata; decides nothing


@dataclasses.dataclass(frozen=True)
class LoadContext:
    """Everything needed to turn a run directory into a `Method`."""

    run_dir: Path | None  # None for methods that learn nothing
    backbone: str
    parser: str = "offline"  # parser name for methods that parse (models.parsing.make_parser)
    num_samples: int = 1024
    threshold: float = 0.0  # EvalSettings.threshold: least grounding probability to place against (0: always)
    inference: InferenceSettings | None = None  # a policy row's placement-time settings; None: the policy's defaults

    @property
    def trained_run(self) -> Path:
        """`run_dir`, for a method that loads a trained run (EvaluationError without one)."""
        if self.run_dir is None:
            raise EvaluationError(
                "this method loads a trained run and none was given: train it first "
                "(`ocplace reproduce` trains missing runs)"
            )
        return self.run_dir


@dataclasses.dataclass(frozen=True)
class MethodSpec(Generic[RecipeT]):
    name: str  # command-line key, e.g. "ours", "no_adapter", "no_llm", "no_pretrain", "grids", "cliport"
    label: str  # the row of Table I, e.g. "Ours w/o Adapter"
    load: Callable[[LoadContext], Method]
    train: Callable[[TrainContext[RecipeT]], Path] | None = None  # returns the run directory; None: learns nothing
    # Makes the cached inputs that all of this method's trainings read (e.g. the training split's features)
    # once, before those trainings run side by side; None: nothing shared to make.
    prepare: Callable[[TrainContext[RecipeT]], object] | None = None
    # Its evaluations encode the test scenes with the experiment's backbone through the shared store
    # (models/shared_features.py), so one evaluation's features serve the others.
    shares_test_features: bool = False
    # It trains or places on the experiment's pretrained backbone, so `reproduce` repeats it over backbone seeds
    # (`EvalPlan.backbone_seeds`); False for a method that starts from random weights.
    uses_backbone: bool = True
    # An inference-only row: it places with this row's trained runs (loading them its own way, e.g. with other
    # inference settings) and trains nothing; `reproduce` trains the owner's runs when only this row is selected.
    places_with: str | None = None

    @property
    def trained_as(self) -> str:
        """The row whose training makes this row's runs (its own name, unless it places with another's)."""
        return self.places_with or self.name

    @property
    def needs_run(self) -> bool:
        """It loads a trained run: its own training's, or the row's it places with."""
        return self.train is not None or self.places_with is not None


def done_record(run_dir: Path) -> Path:
    """Where a finished training of `run_dir` is recorded, with its context: beside the run directory."""
    return run_dir.with_name(run_dir.name + ".done.json")


def finished_run(context: TrainContext[Any]) -> Path | None:
    """The run directory of a finished training of exactly this context (its record), else None."""
    record = done_record(Path(context.out_dir))
    if not record.exists():
        return None
    done = json.loads(record.read_text())
    same = done["context"] == serial.to_dict(dataclasses.asdict(context)) and Path(done["run_dir"]).exists()
    return Path(done["run_dir"]) if same else None


def train_once(spec: MethodSpec[Any], context: TrainContext[Any]) -> tuple[Path, bool]:
    """(run directory, reused), for `reproduce` and `ocplace train --method`: a finished training of exactly this
    context is not called again (its inputs not even loaded; the training itself would write nothing:
    `train/runner.py`); else the row trains (its shared inputs `prepare`d before) and the record is written."""
    from ocplace.paths import write_text_atomic

    if spec.train is None:
        raise EvaluationError(f"{spec.name} learns nothing: there is no run to train (evaluate it directly)")
    done = finished_run(context)
    if done is not None:
        return done, True
    run_dir = Path(spec.train(context))
    wanted = serial.to_dict(dataclasses.asdict(context))
    write_text_atomic(
        done_record(Path(context.out_dir)), json.dumps({"context": wanted, "run_dir": str(run_dir)}, indent=1)
    )
    return run_dir, False
