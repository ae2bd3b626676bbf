"""95% intervals of a success rate over test scenes and repeated runs (seeds of the adapters, of the backbone).

Every run of a row is scored on the same scenes, so the scenes are one source of variation shared by the
runs and the seeds another. The interval is a two-level bootstrap: each replicate draws runs with
replacement and, independently, scenes with replacement (the same scenes for every drawn run), and takes
the mean success; its 2.5% and 97.5% quantiles bound the interval. A bootstrap over few runs, or over
scenes that all succeed, can come out narrower than the scenes alone allow, so the interval is widened to
hold the Wilson score interval of the mean rate at the number of scenes: averaging seeds on the same
scenes never makes the scene sample larger. NumPy (and SciPy's normal quantile); deterministic, with a fixed
bootstrap seed.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

LEVEL = 0.95
RESAMPLES = 2000
BOOTSTRAP_SEED = 0


class Interval(NamedTuple):
    mean: float  # over runs and scenes, in [0, 1]
    low: float
    high: float
    runs: int
    scenes: int


def wilson(rate: float, scenes: int, level: float = LEVEL) -> tuple[float, float]:
    """The Wilson score interval of a rate observed on `scenes` scenes."""
    z = _normal_quantile(0.5 + level / 2)
    centre = (rate + z * z / (2 * scenes)) / (1 + z * z / scenes)
    half = z * math.sqrt(rate * (1 - rate) / scenes + z * z / (4 * scenes * scenes)) / (1 + z * z / scenes)
    return max(0.0, centre - half), min(1.0, centre + half)


def success_interval(
    successes: np.ndarray, level: float = LEVEL, resamples: int = RESAMPLES, seed: int = BOOTSTRAP_SEED
) -> Interval:
    """The interval of the mean of `successes`, `(runs, scenes)` bool or 0/1: each run scored on the same
    scenes, in the same order. Raises ValueError for an empty array."""
    successes = np.asarray(successes, np.float64)
    low, high = _bootstrap(successes, level, resamples, seed)
    runs, scenes = successes.shape
    mean = float(successes.mean())
    wilson_low, wilson_high = wilson(mean, scenes, level)
    return Interval(mean, float(min(low, wilson_low)), float(max(high, wilson_high)), runs, scenes)


def paired_interval(
    differences: np.ndarray, level: float = LEVEL, resamples: int = RESAMPLES, seed: int = BOOTSTRAP_SEED
) -> Interval:
    """The interval of the mean of `differences`, `(units, scenes)` in [-1, 1]: one row's success minus another's on
    the same scenes, per unit of runs. The two-level bootstrap alone (no Wilson floor: a difference of paired
    outcomes is no rate)."""
    differences = np.asarray(differences, np.float64)
    low, high = _bootstrap(differences, level, resamples, seed)
    units, scenes = differences.shape
    return Interval(float(differences.mean()), float(low), float(high), units, scenes)


def _bootstrap(values: np.ndarray, level: float, resamples: int, seed: int) -> tuple[float, float]:
    """The two-level bootstrap's quantiles of the mean of `values` `(runs, scenes)`; ValueError when it is empty."""
    if values.ndim != 2 or 0 in values.shape:
        raise ValueError(f"values must be (runs, scenes) with at least one of each, got shape {values.shape}")
    runs, scenes = values.shape
    rng = np.random.default_rng(seed)
    run_counts = _counts(rng.integers(runs, size=(resamples, runs)), runs)  # (resamples, runs)
    scene_counts = _counts(rng.integers(scenes, size=(resamples, scenes)), scenes)  # (resamples, scenes)
    # The mean over drawn runs and drawn scenes: per scene the drawn runs' mean, then over drawn scenes.
    per_scene = run_counts @ values / runs  # (resamples, scenes)
    replicates = np.einsum("rs,rs->r", per_scene, scene_counts) / scenes
    tail = (1 - level) / 2
    low, high = np.quantile(replicates, [tail, 1 - tail])
    return float(low), float(high)


def _counts(drawn: np.ndarray, size: int) -> np.ndarray:
    """`(rows, size)` how often each index is drawn in each row of `drawn` `(rows, draws)`."""
    rows = np.repeat(np.arange(len(drawn)), drawn.shape[1])
    return np.bincount(rows * size + drawn.ravel(), minlength=len(drawn) * size).reshape(len(drawn), size)


def _normal_quantile(p: float) -> float:
    from scipy.stats import norm

    return float(norm.ppf(p))
