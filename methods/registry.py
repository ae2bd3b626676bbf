"""Which methods `ocplace evaluate` and `reproduce` know: every folder of `ocplace.methods` with a `method.py` is a
row named after its folder, and so is every package another distribution names in the entry-point group
`ocplace.methods` (`name = package`). A row's package sets its place in Table I (`TABLE_ROW`) and, if it learns
with a recipe, that recipe's type (`RECIPE`, the type of its entry in `Experiment.recipes`) in its JAX-free
`__init__.py`, and exposes `SPEC` (a MethodSpec) in `method.py`. No list restates them (docs/architecture.md)."""

from __future__ import annotations

import dataclasses
import importlib
import importlib.metadata
import pkgutil
from pathlib import Path
from typing import Any

from ocplace import methods
from ocplace.errors import EvaluationError
from ocplace.eval.api import Method
from ocplace.eval.harness import EvalSettings, MethodRun
from ocplace.methods.contract import LoadContext, MethodSpec, Recipe
from ocplace.models.inference_settings import InferenceSettings

ENTRY_POINTS = "ocplace.methods"


def row_packages() -> dict[str, str]:
    """Each row's package by its command-line name, in Table I's order (`all`, runs, results.json), read from
    the packages' light `__init__` modules without importing JAX."""
    packages = {
        row.name: f"{methods.__name__}.{row.name}"
        for row in pkgutil.iter_modules(methods.__path__)
        if row.ispkg and (Path(getattr(row.module_finder, "path", "")) / row.name / "method.py").is_file()
    }
    for entry in importlib.metadata.entry_points(group=ENTRY_POINTS):
        if entry.name in packages:
            raise EvaluationError(f"{entry.value} registers {entry.name!r}, a row {packages[entry.name]} has")
        packages[entry.name] = entry.value
    places = {}
    for name, package_name in packages.items():
        try:
            package = importlib.import_module(package_name)
        except ImportError as error:  # an entry point naming a package that is not installed, or is broken
            raise EvaluationError(
                f"row {name!r}: its package {package_name} does not import ({error}); install it, or uninstall the "
                f"distribution that names it in the entry-point group {ENTRY_POINTS}"
            ) from error
        place = getattr(package, "TABLE_ROW", None)
        if not isinstance(place, int):
            raise EvaluationError(f"{package_name} must set TABLE_ROW, the row's place in Table I (an int)")
        places[name] = place
    return {name: packages[name] for name in sorted(packages, key=lambda name: (places[name], name))}


def registered_names() -> tuple[str, ...]:
    """The rows' command-line names in Table I's order, known without importing JAX."""
    return tuple(row_packages())


def recipe_types() -> dict[str, type[Recipe]]:
    """The recipe type of each row that learns with one (its package's `RECIPE`), by name, without importing JAX."""
    packages = {name: importlib.import_module(package) for name, package in row_packages().items()}
    types = {name: package.RECIPE for name, package in packages.items() if hasattr(package, "RECIPE")}
    for name, recipe_type in types.items():
        if not (isinstance(recipe_type, type) and dataclasses.is_dataclass(recipe_type)):
            raise EvaluationError(f"row {name!r}: RECIPE must be a dataclass type (experiments are saved as JSON)")
    return types


def recipe_presets(scale: str) -> dict[str, Recipe]:
    """Each learning row's recipe at an experiment's `scale` (its package's `PRESETS[scale]`, beside `RECIPE`): what
    configs/<scale>.py trains with, so that every value of a row's recipe lives in its own recipe.py. A row from
    outside the tree without presets is left out (`Experiment.recipe` falls back on its `RECIPE`'s defaults);
    EvaluationError when a row has presets but none for `scale`."""
    presets = {}
    for name, package in ((n, importlib.import_module(p)) for n, p in row_packages().items()):
        if hasattr(package, "RECIPE") and hasattr(package, "PRESETS"):
            if scale not in package.PRESETS:
                raise EvaluationError(
                    f"row {name!r} has no recipe for {scale!r} (its PRESETS: {', '.join(package.PRESETS)})"
                )
            presets[name] = package.PRESETS[scale]
    return presets


def inference_defaults() -> dict[str, InferenceSettings]:
    """The placement-time settings of each policy row (its package's `INFERENCE`), by name, without importing JAX:
    what an experiment's `inference` starts from."""
    packages = {name: importlib.import_module(package) for name, package in row_packages().items()}
    defaults = {name: package.INFERENCE for name, package in packages.items() if hasattr(package, "INFERENCE")}
    for name, settings in defaults.items():
        if not isinstance(settings, InferenceSettings):
            raise EvaluationError(f"row {name!r}: INFERENCE must be an InferenceSettings")
    return defaults


def in_tree(name: str) -> bool:
    """Whether the row `name` is a folder of `ocplace.methods`, not a package another distribution registers."""
    return row_packages()[name].startswith(f"{methods.__name__}.")


def method_specs() -> dict[str, MethodSpec[Any]]:
    """Every registered method by its command-line name, in Table I's order."""
    specs: dict[str, MethodSpec[Any]] = {}
    for name, package_name in row_packages().items():
        spec = importlib.import_module(f"{package_name}.method").SPEC
        if spec.name != name:
            raise EvaluationError(f"{package_name} registers {spec.name!r}: a row is named after its folder")
        specs[name] = spec
    return specs


def select_specs(names: str, specs: dict[str, Any]) -> list[Any]:
    """The specs named in a comma-separated list (`all`: every registered one), in that order."""
    if names.strip() == "all":
        if not specs:
            raise EvaluationError("no method is registered (no folder of ocplace.methods has a method.py)")
        return list(specs.values())
    wanted = [n.strip() for n in names.split(",") if n.strip()]
    unknown = [n for n in wanted if n not in specs]
    if unknown or not wanted:
        raise EvaluationError(f"unknown method(s) {unknown or names!r}; registered: {', '.join(specs) or 'none'}")
    twice = sorted({n for n in wanted if wanted.count(n) > 1})
    if twice:  # it would be evaluated twice and shown in two equal rows
        raise EvaluationError(f"--methods names {', '.join(twice)} twice; name each method once")
    return [specs[n] for n in wanted]


def method_run(
    spec: MethodSpec[Any],
    run_dir: Path | None = None,
    fraction: float = 1.0,
    seed: int | None = None,
    backbone_seed: int | None = None,
    inference: InferenceSettings | None = None,
) -> MethodRun:
    """The harness's row for a run of `spec` (`inference`: None for the row's own, `INFERENCE`)."""
    return MethodRun(spec.name, spec.label, run_dir, fraction, seed, backbone_seed, inference=inference)


def load_method(spec: MethodSpec[Any], run: MethodRun, settings: EvalSettings) -> Method:
    """The `Method` of `run`, loaded by its spec with the settings' backbone, parser and sample count, and the run's
    inference settings (None: the row's own)."""
    settings = run.settings(settings)
    context = LoadContext(run.run_dir, settings.backbone, settings.parser, settings.num_samples, settings.threshold)
    return spec.load(dataclasses.replace(context, inference=run.inference))
