"""Which methods `ocplace evaluate` knows: each module listed here exposes `METHODS`, a tuple of MethodSpec."""

from __future__ import annotations

import importlib

from ocplace.eval.api import MethodSpec
from ocplace.eval.harness import EvaluationError

METHOD_MODULES: tuple[str, ...] = ("ocplace.eval.ours", "ocplace.eval.baselines", "ocplace.eval.ablations")


def method_specs() -> dict[str, MethodSpec]:
    """Every registered method by its command-line name, in registration order."""
    specs: dict[str, MethodSpec] = {}
    for module_name in METHOD_MODULES:
        for spec in importlib.import_module(module_name).METHODS:
            if spec.name in specs:
                raise ValueError(f"method {spec.name!r} is registered twice (in {module_name})")
            specs[spec.name] = spec
    return specs


def select_specs(names: str, specs: dict) -> list:
    """The specs named in a comma-separated list (`all`: every registered one), in that order."""
    if names.strip() == "all":
        if not specs:
            raise EvaluationError("no method is registered (ocplace.eval.registry.METHOD_MODULES is empty)")
        return list(specs.values())
    wanted = [n.strip() for n in names.split(",") if n.strip()]
    unknown = [n for n in wanted if n not in specs]
    if unknown or not wanted:
        raise EvaluationError(f"unknown method(s) {unknown or names!r}; registered: {', '.join(specs) or 'none'}")
    return [specs[n] for n in wanted]
