"""Which training examples each step reads: seeded nested subsets and epoch-wise shuffles, shared by every
training so that a run's example order is a pure function of its seeds (and so resumes exactly)."""

from __future__ import annotations

import numpy as np

from ocplace import serial
from ocplace.errors import TrainingError


def check_run_keys(seed: int, fraction: float) -> None:
    """Refuses a run's seed or share of the training split that no run can have."""
    if seed < 0 or not 0.0 < fraction <= 1.0:
        raise TrainingError(f"a run's seed is at least 0 and its fraction lies in (0, 1], got {seed}, {fraction}")


def run_config(recipe: object, seed: int, fraction: float) -> dict:
    """What a run recorded of how it trained (its `run.json` and its weights file): the recipe, and the seed and
    fraction its context gave it."""
    return {"recipe": serial.to_dict(recipe), "seed": seed, "fraction": fraction}


def subset_indices(num_scenes: int, fraction: float, subset_seed: int) -> np.ndarray:
    """Sorted indices of a seeded `fraction` of the scenes; smaller fractions are prefixes of larger."""
    count = max(1, round(fraction * num_scenes))
    return np.sort(np.random.default_rng(subset_seed).permutation(num_scenes)[:count])


def batch_indices(num_examples: int, seed: int, start_step: int, num_steps: int, batch_size: int) -> np.ndarray:
    """int32 `(num_steps, batch_size)` example indices of steps `start_step ...`: epoch-wise shuffles."""
    flat = np.arange(start_step * batch_size, (start_step + num_steps) * batch_size)
    epochs, positions = np.divmod(flat, num_examples)
    indices = np.empty_like(flat)
    for epoch in np.unique(epochs):
        in_epoch = epochs == epoch
        indices[in_epoch] = np.random.default_rng([seed, int(epoch)]).permutation(num_examples)[positions[in_epoch]]
    return indices.reshape(num_steps, batch_size).astype(np.int32)
