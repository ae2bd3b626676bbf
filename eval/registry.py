"""Which methods `ocplace evaluate` knows: each module listed here exposes `METHODS`, a tuple of MethodSpec."""

from __future__ import annotations

import importlib

from ocplace.eval.api import MethodSpec

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
