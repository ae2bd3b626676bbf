"""What one experiment decides, as one tree of frozen dataclasses.

`ocplace.configs` holds one `Experiment` per file (smoke, demo, default); `ocplace reproduce`
runs one. Every row that learns finds its training recipe in `Experiment.recipes` under its registered
name; the recipe's type is the row's own (`RECIPE` in its JAX-free package, `ocplace.methods.registry`), so
building, checking and reading back an experiment is fast and names no row here. The pipeline hands the
recipe to the row through `TrainContext.recipe`.
"""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Callable, Collection, Iterable, Mapping
from pathlib import Path
from typing import Any, TypeVar

from ocplace import serial
from ocplace.errors import ConfigError, OcplaceError
from ocplace.methods import registry
from ocplace.methods.contract import Recipe
from ocplace.models.inference_settings import InferenceSettings
from ocplace.models.offline_recipes import PretrainConfig
from ocplace.models.parsing.config import PARSER_NAMES
from ocplace.runtime.width import TRAIN_CPUS
from ocplace.vocabulary import MAX_SAMPLES, MAX_SEED, TEST_SUBSETS, subsets_problem

RecipeT = TypeVar("RecipeT")


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
        return problems


_SCENE_COUNTS = ("train_scenes", "test_scenes")

# Keys a training run takes from its context, not from a recipe (`TrainContext`), and where they are set.
RUN_FIELDS = {
    "seed": "the experiment's `seed` (and `evaluation.seeds` for repeats)",
    "fraction": "`evaluation.fractions`",
}
_RUN_KEY = re.compile(rf"recipes\.[^.]+\.({'|'.join(RUN_FIELDS)})")


def read_overrides(overrides: Iterable[str]) -> list[str]:
    """`--set KEY=VALUE` items, once none of them sets a key that a training run takes from its context
    (`recipes.ROW.seed`, `recipes.ROW.fraction`: ConfigError naming each, with where to set it)."""
    overrides = list(overrides)
    keys = [item.partition("=")[0].strip() for item in overrides]
    refused = [
        f"{key} is set for each run from {RUN_FIELDS[match.group(1)]}; change that instead"
        for key in keys
        if (match := _RUN_KEY.fullmatch(key))
    ]
    if refused:
        raise ConfigError("; ".join(refused))
    return overrides


def read_recipes(recipes: Mapping[str, Any]) -> dict[str, Recipe]:
    """`Experiment.recipes` from its JSON text: each entry rebuilt as its row's registered `RECIPE` type."""
    types = registry.recipe_types()
    unknown = [name for name in recipes if name not in types]
    if unknown:
        raise ConfigError(
            f"recipes holds {', '.join(unknown)}, no registered row that learns with a recipe "
            f"(those: {', '.join(types)})"
        )
    return {name: serial.from_dict(types[name], fields) for name, fields in recipes.items()}


def recipe_problems(recipes: Mapping[str, Any]) -> list[str]:
    """What each recipe's own `validate` refuses, and each entry that is not its row's registered type, by key."""
    types = registry.recipe_types()
    problems = []
    for name, recipe in recipes.items():
        if name not in types:
            problems.append(f"recipes.{name} names no row that learns with a recipe (those: {', '.join(types)})")
        elif not isinstance(recipe, types[name]):
            problems.append(f"recipes.{name} is a {type(recipe).__name__}; {name} learns with a {types[name].__name__}")
        elif problem := _refusal(f"recipes.{name}", recipe.validate):
            problems.append(problem)
    return problems


def read_inference(inference: Mapping[str, Any]) -> dict[str, InferenceSettings]:
    """`Experiment.inference` from its JSON text."""
    return {name: serial.from_dict(InferenceSettings, fields) for name, fields in inference.items()}


def inference_problems(inference: Mapping[str, Any]) -> list[str]:
    """Each entry that names no policy row (a registered row declaring `INFERENCE`) or cannot place, by key."""
    rows = registry.inference_defaults()
    problems = []
    for name, settings in inference.items():
        if name not in rows:
            problems.append(f"inference.{name} names no policy row (those: {', '.join(rows)})")
        elif not isinstance(settings, InferenceSettings):
            problems.append(f"inference.{name} is a {type(settings).__name__}, not an InferenceSettings")
        else:
            problems += [f"inference.{name}.{problem}" for problem in settings.problems()]
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
        for key in ("methods", "fraction_methods", "seed_methods"):
            names = getattr(self, key) or ()
            twice = sorted({name for name in names if names.count(name) > 1})
            problems += [f"evaluation.{key} names {', '.join(twice)} twice; name each method once"] if twice else []
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
    # Each learning row's recipe by its registered name, of that row's `RECIPE` type (read back by it).
    recipes: Mapping[str, Recipe] = dataclasses.field(metadata={serial.READ: read_recipes})
    evaluation: EvalPlan
    cpus: TaskCpus = TaskCpus()
    # Each policy row's placement-time settings by its registered name (`INFERENCE` of its package, unless an
    # experiment sets them): how it places with its trained runs; `--set inference.ROW.FIELD=VALUE`.
    inference: Mapping[str, InferenceSettings] = dataclasses.field(
        default_factory=registry.inference_defaults, metadata={serial.READ: read_inference}
    )

    def backbone_recipe(self, seed: int | None = None) -> PretrainConfig:
        """The backbone's pretraining recipe, with another optimiser seed for a backbone repeat (None: its own)."""
        if seed is None:
            return self.backbone
        return dataclasses.replace(self.backbone, optim=dataclasses.replace(self.backbone.optim, seed=seed))

    def backbone_seeds(self) -> list[int]:
        """The optimiser seeds of the backbone's repeats (`evaluation.backbone_seeds`), after its own."""
        first = self.backbone.optim.seed
        return list(range(first + 1, first + self.evaluation.backbone_seeds))

    def recipe(self, method: str) -> Any:
        """The recipe of a registered row: its entry here, else its `RECIPE`'s defaults (for a row from outside the
        tree, which no experiment of ours names: `missing_recipes` refuses one of ours); None for a row that learns
        without one."""
        if method in self.recipes:
            return self.recipes[method]
        recipe_type = registry.recipe_types().get(method)
        return None if recipe_type is None else recipe_type()

    def recipe_as(self, method: str, kind: type[RecipeT]) -> RecipeT:
        """`recipe(method)`, which must be a `kind` (a script's typed view of one row's recipe); ConfigError
        naming both types otherwise."""
        recipe = self.recipe(method)
        if not isinstance(recipe, kind):
            raise ConfigError(f"{method}'s recipe is a {type(recipe).__name__}, not a {kind.__name__}")
        return recipe

    def missing_recipes(self, methods: Iterable[str]) -> list[str]:
        """For each of `methods` that learns with a recipe this experiment does not hold, what to add: every row of
        the tree needs its entry; a row from outside falls back on its `RECIPE`'s defaults, if it has them."""
        types = registry.recipe_types()
        return [
            f"recipes has no entry for {name}, which learns with a {types[name].__name__}: add one to the experiment"
            for name in methods
            if name in types and name not in self.recipes and (registry.in_tree(name) or not _has_defaults(types[name]))
        ]

    def validate(self) -> None:
        """Raises ConfigError, naming every key whose value cannot work, before any work starts: counts and
        ranges, finite numbers, positive learning rates, known subsets and parser, each recipe's own checks.
        The method names are checked by the pipeline, which knows the registered methods."""
        problems = [] if self.name else ["name must not be empty"]
        if 0 <= self.seed <= MAX_SEED < self.seed + self.evaluation.seeds - 1:  # repeats' seeds follow the experiment's
            problems.append(f"seed + evaluation.seeds - 1 must be at most {MAX_SEED:,}, got {self.seed}")
        problems += self.dataset.problems() + self.evaluation.problems() + recipe_problems(self.recipes)
        problems += inference_problems(self.inference)
        problems += [problem for problem in [_refusal("backbone", self.backbone.validate)] if problem]
        problems += number_problems(self, "")
        if problems:
            raise ConfigError(
                f"experiment {self.name!r} cannot run: {'; '.join(problems)}. Change the value with "
                "--set KEY=VALUE, or in the experiment's file in configs/"
            )


def _has_defaults(recipe_type: type) -> bool:
    return all(
        field.default is not dataclasses.MISSING or field.default_factory is not dataclasses.MISSING
        for field in dataclasses.fields(recipe_type)
        if field.init
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
    `warmup_steps` at least 0, every `seed` and `*_seed` one numpy and JAX take."""
    if dataclasses.is_dataclass(node):
        return [
            problem
            for field in dataclasses.fields(node)
            for problem in number_problems(getattr(node, field.name), f"{key}.{field.name}".lstrip("."))
        ]
    if isinstance(node, Mapping):
        return [problem for name, item in node.items() for problem in number_problems(item, f"{key}.{name}")]
    if isinstance(node, tuple):
        return [problem for index, item in enumerate(node) for problem in number_problems(item, f"{key}[{index}]")]
    if isinstance(node, float) and not math.isfinite(node):
        return [f"{key} is {node}; numbers must be finite"]
    name = key.rsplit(".", 1)[-1]
    if name == "learning_rate" and isinstance(node, int | float) and not node > 0:
        return [f"{key} must be positive, got {node}"]
    if name == "warmup_steps" and isinstance(node, int) and node < 0:
        return [f"{key} must be at least 0, got {node}"]
    if (name == "seed" or name.endswith("_seed")) and isinstance(node, int) and not 0 <= node <= MAX_SEED:
        return [f"{key} must be from 0 to {MAX_SEED:,} (what numpy and JAX seed from), got {node}"]
    return []
