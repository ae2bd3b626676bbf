"""The contract between the evaluation harness and the methods of Table I.

A method is registered as a `MethodSpec`: how to train it (if it learns anything) and how to load a
trained run into a `Method` that places the held object in dataset scenes. The harness owns scoring:
methods never see the ground truth (tuples, oracle, GT tokens), only what a robot would have: the
RGB-D image, the boxes from segmentation, the scene objects' table-frame AABBs of those boxes, the
instruction, the held object's footprint and the camera.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from ocplace.sim.dataset.records import SceneRecord


@dataclasses.dataclass(frozen=True)
class MethodOutput:
    """What one method did in one scene; the harness scores it."""

    mode: np.ndarray | None  # (2,) table-frame metres of the most probable placement; None: no placement
    samples: np.ndarray | None  # (num_samples, 2) table-frame metres; None: the method has no samples
    parsed: tuple[tuple[str, str], ...] | None = None  # (reference phrase, canonical relation) per tuple
    grounded: tuple[int, ...] | None = None  # visual-token index per parsed tuple (N = the table)
    failure: str | None = None  # why there is no placement (typed error message or flag), else None
    parse_note: str | None = None  # the LLM parser's fall-back reason or its disagreement with the offline parse


class Method(Protocol):
    """A trained method, ready to place."""

    name: str

    def describe(self) -> dict:
        """JSON-able: configs, seeds, checkpoint sha256, backbone fingerprint, parser and its cache."""

    def run(self, scenes: Sequence[SceneRecord], key) -> list[MethodOutput]:
        """One output per scene, in order. Must not read the records' tuples, oracle or token indices."""


@dataclasses.dataclass(frozen=True)
class TrainContext:
    """Everything a method's training needs; `out_dir` is its run directory (resumable)."""

    dataset_dir: Path
    backbone: str  # backbone spec, e.g. "offline" or "clip:/path"
    out_dir: Path
    recipe: Any = None  # the method's own training config (`Experiment.recipes.of(name)`); fraction and seed apart
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


@dataclasses.dataclass(frozen=True)
class MethodSpec:
    name: str  # command-line key, e.g. "ours", "no_adapter", "no_llm", "no_pretrain", "grids", "cliport"
    label: str  # the row of Table I, e.g. "Ours w/o Adapter"
    load: Callable[[LoadContext], Method]
    train: Callable[[TrainContext], Path] | None = None  # returns the run directory; None: nothing to train
    # Makes the cached inputs that all of this method's trainings read (e.g. the training split's features)
    # once, before those trainings run side by side; None: nothing shared to make.
    prepare: Callable[[TrainContext], object] | None = None
