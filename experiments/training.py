"""One registered row trained on its own (`ocplace train --method`), exactly as a task of `reproduce` trains it:
its spec's shared inputs made first, then its run, reused when one with the same context is done."""

from __future__ import annotations

from pathlib import Path

from ocplace.errors import ConfigError
from ocplace.experiments.experiment import Experiment
from ocplace.methods.contract import TrainContext, finished_run, train_once
from ocplace.methods.registry import method_specs
from ocplace.runtime.width import pin_jax_width


def train_row(
    method: str,
    experiment: Experiment,
    dataset: Path,
    backbone: str,
    out: Path,
    seed: int,
    fraction: float,
    cpus: int = 0,
) -> tuple[Path, bool, str]:
    """`(run directory, reused, the row's label)` of `method` trained with `experiment`'s recipe; ConfigError for a
    row that trains nothing or a recipe the experiment lacks. `cpus` (0: all) pins JAX's width before it starts,
    as each task of `reproduce` does: the width decides the last bits."""
    specs = method_specs()
    if method not in specs:
        raise ConfigError(f"unknown method {method!r}; registered: {', '.join(specs)}")
    spec = specs[method]
    if spec.places_with is not None:
        raise ConfigError(
            f"{method} trains nothing: it places with {spec.places_with}'s runs; train those "
            f"(`ocplace train --method {spec.places_with}`) and evaluate {method} on them"
        )
    if spec.train is None:
        raise ConfigError(f"{method} learns nothing: there is no run to train (evaluate it directly)")
    experiment.validate()
    if missing := experiment.missing_recipes([method]):
        raise ConfigError(f"experiment {experiment.name!r} cannot train {method}: {missing[0]}")
    context = TrainContext(dataset, backbone, out, experiment.recipe(method), fraction, seed, experiment.name)
    if cpus:
        pin_jax_width(cpus)
    if spec.prepare is not None and finished_run(context) is None:
        spec.prepare(context)
    run_dir, reused = train_once(spec, context)
    return run_dir, reused, spec.label
