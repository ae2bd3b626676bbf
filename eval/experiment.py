"""What one experiment scale decides, as one tree of frozen dataclasses.

`ocplace.configs` holds one `Experiment` per scale (smoke, demo, default); `ocplace reproduce`
runs one. Every method that learns finds its training recipe here by its registered name
(`MethodRecipes.of`); the pipeline hands it to the method through `TrainContext.recipe`.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from ocplace.errors import ConfigError
from ocplace.models.offline_recipes import PretrainConfig
from ocplace.train.cliport import CliportRecipe
from ocplace.train.config import TrainConfig
from ocplace.train.grids import GridsRecipe
from ocplace.train.no_llm import NoLlmTrainConfig
from ocplace.train.no_pretrain import NoPretrainRecipe


@dataclasses.dataclass(frozen=True)
class DatasetSizes:
    """The generated benchmark: how many scenes, and how many of them get the physical drop check."""

    train_scenes: int
    test_scenes: int  # per test subset
    physical_scenes: int | None  # first K scenes per test subset get the drop check; None: all, 0: none
    seed: int  # scene generation


@dataclasses.dataclass(frozen=True)
class MethodRecipes:
    """The training configuration of each method that learns, keyed by its registered name."""

    ours: TrainConfig
    no_llm: NoLlmTrainConfig
    no_pretrain: NoPretrainRecipe
    grids: GridsRecipe
    cliport: CliportRecipe

    def of(self, method: str):
        """The recipe of a registered method; None for a method without one (it learns nothing)."""
        return getattr(self, method) if method in {field.name for field in dataclasses.fields(self)} else None


@dataclasses.dataclass(frozen=True)
class EvalPlan:
    """Which methods run, on which training fractions, and how they are scored."""

    methods: tuple[str, ...] | None  # None: every registered method
    fractions: tuple[float, ...]  # training-set shares of the sample-efficiency study (1.0 always runs)
    fraction_methods: tuple[str, ...]  # the methods trained on every fraction
    num_samples: int  # placement samples per scene
    parser: str  # models.parsing.make_parser name, for methods that parse
    subsets: tuple[str, ...]  # test subsets scored
    seeds: int  # each run trained and scored with this many seeds (the experiment's, then the next ones)
    seed_methods: tuple[str, ...] | None = None  # the methods repeated over `seeds`; None: every method
    seed_fractions: tuple[float, ...] | None = None  # the fractions repeated over `seeds`; None: every one


@dataclasses.dataclass(frozen=True)
class TaskCpus:
    """The CPUs `reproduce`'s pretraining and training tasks declare, and so the width of their JAX, which
    decides the last bits of what they learn (docs/distributed.md). Evaluations declare one CPU."""

    pretrain: int = 2
    train: int = 2  # each training, and the inputs trainings share (features)

    def __post_init__(self):
        if min(self.pretrain, self.train) < 1:
            raise ConfigError(f"task CPUs must be at least 1, got {self}")


@dataclasses.dataclass(frozen=True)
class Experiment:
    name: str  # recorded in results.json (EvalSettings.scale) and in baseline run metadata
    out: Path  # `ocplace reproduce`'s output folder unless --out is given
    seed: int  # training and evaluation
    dataset: DatasetSizes
    backbone: PretrainConfig  # the offline backbone's pretraining recipe; its hash names its cache folder
    recipes: MethodRecipes
    evaluation: EvalPlan
    cpus: TaskCpus = TaskCpus()
