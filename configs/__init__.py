"""The experiments, one file each: each `get_config()` spells out everything its experiment decides.

    smoke     tests and CI: 12 + 4 x 8 scenes, seconds-long recipes
    demo      `make demo`: 200 + 4 x 40 scenes, Ours, w/o Adapter and w/o LLM, 5 to 8 min on 2 cores
    default   the paper's protocol: 2000 + 4 x 400 scenes, every method and training fraction

`get(name)` returns the named `Experiment`; `ocplace reproduce --experiment NAME` runs it. Their names
are `ocplace.vocabulary.EXPERIMENT_NAMES`, which the CLI offers without importing this package.
"""

from __future__ import annotations

from collections.abc import Callable

from ocplace.configs import default, demo, smoke
from ocplace.errors import UnknownExperiment
from ocplace.experiments.experiment import Experiment

EXPERIMENTS: dict[str, Callable[[], Experiment]] = {
    "smoke": smoke.get_config,
    "demo": demo.get_config,
    "default": default.get_config,
}


def get(name: str) -> Experiment:
    if name not in EXPERIMENTS:
        raise UnknownExperiment(f"unknown experiment {name!r}; choose one of {', '.join(EXPERIMENTS)}")
    return EXPERIMENTS[name]()
