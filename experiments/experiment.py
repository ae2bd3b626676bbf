"""What one experiment decides, as one tree of frozen dataclasses.

`ocplace.configs` holds one `Experiment` per file (smoke, demo, default); `ocplace reproduce`
runs one. Every method that learns finds its training recipe here by its registered name
(`MethodRecipes.of`), typed with that method's `Recipe` (`ocplace.methods`; the types live in the
JAX-free `methods/ours/recipe.py` and `train/schedule.py`, so building and checking an experiment is fast);
the pipeline hands it to the method through `TrainContext.recipe`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Collection, Iterable
from pathlib import Path
from typing import Any

from ocplace.errors import ConfigError, OcplaceError
from ocplace.methods.cliport.recipe import CliportRecipe
from ocplace.methods.grids.recipe import GridsRecipe
from ocplace.methods.no_llm.recipe import NoLlmRecipe
from ocplace.methods.no_pretrain.recipe import NoPretrainRecipe
from ocplace.methods.ours.recipe import OursRecipe
from ocplace.models.offline_recipes import PretrainConfig
from ocplace.models.parsing.config import PARSER_NAMES
from ocplace.runtime.width import TRAIN_CPUS
from ocplace.vocabulary import MAX_SAMPLES, TEST_SUBSETS, subsets_problem


@dataclasses.dataclass(frozen=True)
class DatasetSizes:
    """The generated benchmark: how many scenes, and how many of them get the physical drop check."""

    train_scenes: int
    test_scenes: int  # per test subset
    physical_scenes: int | None  # first K scenes per test subset get the drop check; None: all, 0: none
    seed: int  # scene generation

    def problems(self) -> list[str]:
        problems = [
            f"dataset.{name} must be at least 1, got {getattr(self, name)}"
            for name in _SCENE_COUNTS
            if getattr(self, name) < 1
        ]
        if self.physical_scenes is not None and self.physical_scenes < 0:
            problems.append(f"dataset.physical_scenes must be none (all) or at least 0, got {self.physical_scenes}")
        if self.seed < 0:
            problems.append(f"dataset.seed must be at least 0, got {self.seed}")
        return problems


_SCENE_COUNTS = ("train_scenes", "test_scenes")

# Keys a training run takes from its context, not from a recipe (`TrainContext`), and where they are set.
RUN_KEYS = {
    f"recipes.{recipe}.{field}": source
    for recipe in ("ours", "ours_paper", "no_llm", "no_pretrain")
    for field, source in (
        ("seed", "the experiment's `seed` (and `evaluation.seeds` for repeats)"),
        ("fraction", "`evaluation.fractions`"),
    )
}


def read_overrides(overrides: Iterable[str]) -> list[str]:
    """`--set KEY=VALUE` items, once none of them sets a key that a training run takes from its context
    (`RUN_KEYS`: ConfigError naming each, with where to set it)."""
    overrides = list(overrides)
    keys = [item.partition("=")[0].strip() for item in overrides]
    refused = [
        f"{key} is set for each run from {RUN_KEYS[key]}; change that instead" for key in keys if key in RUN_KEYS
    ]
    if refused:
        raise ConfigError("; ".join(refused))
    return overrides


@dataclasses.dataclass(frozen=True)
class MethodRecipes:
    """The training recipe of each method that learns, keyed by its registered name; each field's type is
    the `Recipe` of that method's module in `ocplace.methods` (imported from `train/`, where it is light)."""

    ours: OursRecipe
    ours_paper: OursRecipe  # the paper's adapters, beside Ours' chosen ones
    no_llm: NoLlmRecipe
    no_pretrain: NoPretrainRecipe
    grids: GridsRecipe
    cliport: CliportRecipe

    def of(self, method: str) -> Any:
        """The recipe of a registered method; None for a method without one (it learns nothing)."""
        return getattr(self, method) if method in {field.name for field in dataclasses.fields(self)} else None

    def problems(self) -> list[str]:
        """What each recipe's own `validate` refuses, named by the recipe's key."""
        checks = {
            "ours": self.ours.validate,
            "ours_paper": self.ours_paper.validate,
            "no_llm": self.no_llm.validate,
            "no_pretrain": self.no_pretrain.validate,
            "grids.schedule": self.grids.schedule.validate,
            "cliport.schedule": self.cliport.schedule.validate,
        }
        problems = [problem for key, check in checks.items() if (problem := _refusal(f"recipes.{key}", check))]
        if self.cliport.num_targets < 1:
            problems.append(f"recipes.cliport.num_targets must be at least 1, got {self.cliport.num_targets}")
        return problems


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
    # The backbone pretrained with this many seeds (the recipe's optimiser seed, then the next ones: the
    # projections' initialisation and the batch order; the same renders); the `seed_methods` on `seed_fractions`
    # that use the backbone are trained and scored on each, beside their own seeds.
    backbone_seeds: int = 1

    def problems(self) -> list[str]:
        problems = []
        if self.methods is not None and not self.methods:
            problems.append("evaluation.methods names no method; name some, or none for every registered method")
        problems += [
            f"evaluation.fractions holds {f}; a training-set fraction lies in (0, 1]"
            for f in self.fractions
            if not 0 < f <= 1
        ]
        if not 1 <= self.num_samples <= MAX_SAMPLES:
            problems.append(f"evaluation.num_samples must be from 1 to {MAX_SAMPLES:,}, got {self.num_samples}")
        if self.parser not in PARSER_NAMES:
            problems.append(
                f"evaluation.parser {self.parser!r} is not a parser; choose one of {', '.join(PARSER_NAMES)}"
            )
        # `reproduce` generates the paper's dataset, without the dev splits (`ocplace evaluate` scores those).
        problem = subsets_problem(self.subsets, "evaluation.subsets", TEST_SUBSETS)
        problems += [problem] if problem else []
        if self.seeds < 1:
            problems.append(f"evaluation.seeds must be at least 1, got {self.seeds}")
        if self.backbone_seeds < 1:
            problems.append(f"evaluation.backbone_seeds must be at least 1, got {self.backbone_seeds}")
        trained = {*self.fractions, 1.0}
        problems += [
            f"evaluation.seed_fractions holds {f}, which is not trained: choose among evaluation.fractions and 1.0"
            for f in self.seed_fractions or ()
            if f not in trained
        ]
        return problems

    def unknown_methods(self, registered: Collection[str]) -> list[str]:
        """The keys of this plan that name a method not in `registered`, with those names."""
        named = {"methods": self.methods, "fraction_methods": self.fraction_methods, "seed_methods": self.seed_methods}
        return [
            f"evaluation.{key} names {', '.join(unknown)}, not registered (registered: {', '.join(registered)})"
            for key, names in named.items()
            if (unknown := [name for name in names or () if name not in registered])
        ]


@dataclasses.dataclass(frozen=True)
class TaskCpus:
    """The CPUs `reproduce`'s pretraining and training tasks declare, and so the width of their JAX, which
    decides the last bits of what they learn (docs/distributed.md). Evaluations declare one CPU."""

    pretrain: int = 2
    train: int = TRAIN_CPUS  # each training, and the inputs trainings share (features)

    def __post_init__(self) -> None:
        if min(self.pretrain, self.train) < 1:
            raise ConfigError(f"task CPUs must be at least 1, got {self}")


@dataclasses.dataclass(frozen=True)
class Experiment:
    name: str  # recorded in results.json (EvalSettings.experiment) and in baseline run metadata (`scale`)
    out: Path  # `ocplace reproduce`'s output folder unless --out is given
    seed: int  # training and evaluation
    dataset: DatasetSizes
    backbone: PretrainConfig  # the offline backbone's pretraining recipe; its hash names its cache folder
    recipes: MethodRecipes
    evaluation: EvalPlan
    cpus: TaskCpus = TaskCpus()

    def backbone_recipe(self, seed: int | None = None) -> PretrainConfig:
        """The backbone's pretraining recipe, with another optimiser seed for a backbone repeat (None: its own)."""
        if seed is None:
            return self.backbone
        return dataclasses.replace(self.backbone, optim=dataclasses.replace(self.backbone.optim, seed=seed))

    def backbone_seeds(self) -> list[int]:
        """The optimiser seeds of the backbone's repeats (`evaluation.backbone_seeds`), after its own."""
        first = self.backbone.optim.seed
        return list(range(first + 1, first + self.evaluation.backbone_seeds))

    def validate(self) -> None:
        """Raises ConfigError, naming every key whose value cannot work, before any work starts: counts and
        ranges, finite numbers, positive learning rates, known subsets and parser, each recipe's own checks.
        The method names are checked by the pipeline, which knows the registered methods."""
        problems = [] if self.name else ["name must not be empty"]
        if self.seed < 0:
            problems.append(f"seed must be at least 0, got {self.seed}")
        problems += self.dataset.problems() + self.evaluation.problems() + self.recipes.problems()
        problems += [problem for problem in [_refusal("backbone", self.backbone.validate)] if problem]
        problems += number_problems(self, "")
        if problems:
            raise ConfigError(
                f"experiment {self.name!r} cannot run: {'; '.join(problems)}. Change the value with "
                "--set KEY=VALUE, or in the experiment's file in ocplace/configs"
            )


def _refusal(key: str, validate: Callable[[], object]) -> str | None:
    """What `validate()` refuses, prefixed by `key`; None when it accepts."""
    try:
        validate()
    except OcplaceError as error:
        return f"{key}: {error}"
    return None


def number_problems(node: object, key: str) -> list[str]:
    """Rules every recipe shares, by field name, anywhere in the tree under `node`: every number is
    finite, every `learning_rate` positive (a negative one trains by gradient ascent), every
    `warmup_steps` at least 0."""
    if dataclasses.is_dataclass(node):
        return [
            problem
            for field in dataclasses.fields(node)
            for problem in number_problems(getattr(node, field.name), f"{key}.{field.name}".lstrip("."))
        ]
    if isinstance(node, tuple):
        return [problem for index, item in enumerate(node) for problem in number_problems(item, f"{key}[{index}]")]
    if isinstance(node, float) and not math.isfinite(node):
        return [f"{key} is {node}; numbers must be finite"]
    name = key.rsplit(".", 1)[-1]
    if name == "learning_rate" and isinstance(node, int | float) and not node > 0:
        return [f"{key} must be positive, got {node}"]
    if name == "warmup_steps" and isinstance(node, int) and node < 0:
        return [f"{key} must be at least 0, got {node}"]
    return []
