"""The optimisers of every training: one learning-rate schedule, Adam, and AdamW for the image towers.

`warmup_cosine` is the schedule of every recipe: a linear warm-up, then cosine decay.

`adam` is Adam as an optax transformation, arranged for fewer passes over memory on CPU.

At batch 1 a step's arithmetic is tiny and Adam's elementwise update of the 262,144 adapter
weights dominates: it streams weights, gradients and both moments (about 4 MB) through the cache
every step. optax's `adam` makes three passes per leaf (first moment, second moment, update) and
three divisions per element. Here both moments of a leaf live in one `(2, *shape)` array updated
in a single in-place pass, and the bias corrections are folded into the step size and epsilon
(Kingma & Ba 2015, end of section 2):

    m <- b1 m + (1 - b1) g,   v <- b2 v + (1 - b2) g^2,   t <- t + 1
    update = -lr_t * sqrt(1 - b2^t) / (1 - b1^t) * m / (sqrt(v) + eps * sqrt(1 - b2^t))

which equals optax's `-lr_t * m_hat / (sqrt(v_hat) + eps)` in exact arithmetic (tests compare
the two). `lr_t` is the schedule at the step index before the update, as in optax.
"""

from __future__ import annotations

import functools
from typing import NamedTuple, Protocol

import jax
import jax.numpy as jnp
import optax


class AdamState(NamedTuple):
    count: jax.Array  # type: ignore[assignment]  # int32 (), steps taken; the name is in every checkpoint's keys
    moments: optax.Updates  # per leaf (2, *shape): first and second moment


def adam(
    learning_rate: optax.ScalarOrSchedule,
    b1: float = 0.9,
    b2: float = 0.999,
    eps: float = 1e-8,
    weight_decay: float = 0.0,
) -> optax.GradientTransformation:
    """Adam; with `weight_decay`, AdamW's decoupled decay (`- lr_t * weight_decay * param`) on every leaf."""

    def init(params) -> AdamState:
        moments = jax.tree_util.tree_map(lambda p: jnp.zeros((2, *p.shape), p.dtype), params)
        return AdamState(jnp.zeros((), jnp.int32), moments)

    def update(grads, state: AdamState, params=None):
        decay = jnp.array([b1, b2], jnp.float32)

        def moments_of(g, mv):
            decay_b = decay.reshape((2,) + (1,) * g.ndim)
            return decay_b * mv + (1.0 - decay_b) * jnp.stack([g, g * g])

        moments = jax.tree_util.tree_map(moments_of, grads, state.moments)
        count = state.count + 1
        t = count.astype(jnp.float32)
        lr = learning_rate(state.count) if callable(learning_rate) else learning_rate
        root = jnp.sqrt(1.0 - b2**t)
        step_size, eps_hat = lr * root / (1.0 - b1**t), eps * root
        updates = jax.tree_util.tree_map(lambda mv: -step_size * mv[0] / (jnp.sqrt(mv[1]) + eps_hat), moments)
        if weight_decay:  # a Python branch: plain Adam compiles exactly as before
            updates = jax.tree_util.tree_map(lambda u, p: u - lr * weight_decay * p, updates, params)
        return updates, AdamState(count, moments)

    return optax.GradientTransformation(init, update)


def warmup_cosine(learning_rate: float, warmup_steps: int, steps: int, end_share: float = 0.0) -> optax.Schedule:
    """Linear warm-up from 0 to `learning_rate` over `warmup_steps`, then cosine decay to
    `end_share * learning_rate` at `steps` (a run shorter than its warm-up still decays one step)."""
    return optax.warmup_cosine_decay_schedule(
        0.0, learning_rate, warmup_steps, max(steps, warmup_steps + 1), learning_rate * end_share
    )


# Image towers (the backbone's pretraining, no_pretrain's tower) decay to this share of the peak, not to 0.
TOWER_END_SHARE = 0.02


class Budget(Protocol):
    """What `make` reads of a training's budget: a `Schedule` (every row's), or the backbone pretraining's
    `OptimConfig`, whose optimiser is a class constant (not serialised: its recipe key stays as it was)."""

    @property
    def learning_rate(self) -> float: ...  # the peak
    @property
    def warmup_steps(self) -> int: ...
    @property
    def steps(self) -> int: ...
    @property
    def weight_decay(self) -> float: ...

    @property
    def optimiser(self) -> str: ...  # "adam" or "adamw_clipped" (an image tower's)


def learning_rates(budget: Budget) -> optax.Schedule:
    """The budget's learning-rate schedule: `warmup_cosine` of its peak, warm-up and steps."""
    end_share = TOWER_END_SHARE if budget.optimiser == "adamw_clipped" else 0.0
    return warmup_cosine(budget.learning_rate, budget.warmup_steps, budget.steps, end_share)


def make(budget: Budget) -> optax.GradientTransformation:
    """The budget's optimiser, the one place every training gets it (as big_vision's `optax.make`): an image
    tower's clipped AdamW; else this module's Adam, with AdamW's decay where the budget sets `weight_decay`."""
    if budget.optimiser == "adamw_clipped":
        return clipped_adamw(learning_rates(budget), budget.weight_decay)
    return adam(learning_rates(budget), weight_decay=budget.weight_decay)


def clipped_adamw(schedule: optax.Schedule, weight_decay: float) -> optax.GradientTransformation:
    """AdamW after clipping the gradient's global norm to 1; weight decay on matrices only (not on norms,
    biases or scales): what trains an image tower, pretrained or from scratch."""
    decay_mask = functools.partial(jax.tree_util.tree_map, lambda p: p.ndim >= 2)
    return optax.chain(
        optax.clip_by_global_norm(1.0), optax.adamw(schedule, weight_decay=weight_decay, mask=decay_mask)
    )
