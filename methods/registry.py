"""Which methods `ocplace evaluate` and `reproduce` know: each module listed here exposes `SPEC`, a MethodSpec."""

from __future__ import annotations

import importlib
from pathlib import Path
from typing import Any

from ocplace.errors import EvaluationError
from ocplace.eval.api import Method
from ocplace.eval.harness import EvalSettings, MethodRun
from ocplace.methods.api import LoadContext, MethodSpec

# One module per row of Table I. The order is the order of `all`, of runs and of results.json's evaluations.
METHOD_MODULES: tuple[str, ...] = (
    "ocplace.methods.ours",
    "ocplace.methods.ours_paper",
    "ocplace.methods.no_adapter",
    "ocplace.methods.grids",
    "ocplace.methods.cliport",
    "ocplace.methods.no_llm",
    "ocplace.methods.no_pretrain",
)


def registered_names() -> tuple[str, ...]:
    """The registered methods' command-line names, known without importing their modules (and JAX): a
    method is named after its module."""
    return tuple(module_name.rsplit(".", 1)[-1] for module_name in METHOD_MODULES)


def method_specs() -> dict[str, MethodSpec[Any]]:
    """Every registered method by its command-line name, in registration order."""
    specs: dict[str, MethodSpec[Any]] = {}
    for module_name, name in zip(METHOD_MODULES, registered_names()):
        spec = importlib.import_module(module_name).SPEC
        if spec.name != name:
            raise ValueError(f"{module_name} registers {spec.name!r}: a method is named after its module")
        specs[spec.name] = spec
    return specs


def select_specs(names: str, specs: dict[str, Any]) -> list[Any]:
    """The specs named in a comma-separated list (`all`: every registered one), in that order."""
    if names.strip() == "all":
        if not specs:
            raise EvaluationError("no method is registered (ocplace.methods.registry.METHOD_MODULES is empty)")
        return list(specs.values())
    wanted = [n.strip() for n in names.split(",") if n.strip()]
    unknown = [n for n in wanted if n not in specs]
    if unknown or not wanted:
        raise EvaluationError(f"unknown method(s) {unknown or names!r}; registered: {', '.join(specs) or 'none'}")
    return [specs[n] for n in wanted]


def method_run(
    spec: MethodSpec[Any],
    run_dir: Path | None = None,
    fraction: float = 1.0,
    seed: int | None = None,
    backbone_seed: int | None = None,
) -> MethodRun:
    """The harness's row for a run of `spec`."""
    return MethodRun(spec.name, spec.label, run_dir, fraction, seed, backbone_seed)


def load_method(spec: MethodSpec[Any], run: MethodRun, settings: EvalSettings) -> Method:
    """The `Method` of `run`, loaded by its spec with the settings' backbone, parser and sample count."""
    settings = run.settings(settings)
    return spec.load(
        LoadContext(run.run_dir, settings.backbone, settings.parser, settings.num_samples, settings.threshold)
    )
