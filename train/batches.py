"""Which training examples each step reads: seeded nested subsets and epoch-wise shuffles, shared by every
training so that a run's example order is a pure function of its seeds (and so resumes exactly)."""

from __future__ import annotations

import numpy as np


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
