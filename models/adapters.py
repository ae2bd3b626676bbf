"""CLIP-Adapters (Gao et al.): a small bottleneck MLP blended residually into frozen CLIP features.

A(x) = ReLU(W2 ReLU(W1 x)) with W1: D -> D/reduction and W2: D/reduction -> D, no biases, and
x* = ratio * A(x) + (1 - ratio) * x. One adapter for the visual tokens, one for the text tokens;
for D = 512 and reduction 4 the pair has 2 * 2 * 512 * 128 = 262,144 parameters.

The paper's blend lets the ratio mean little: a trained A(x) may be several times the norm of x, so a
ratio of 0.2 hands the adapter about half the blended vector. With `normalise`, A(x) is scaled to the
norm of x first, so the ratio is the adapter's share by norm; each tower may have its own ratio
(`text_ratio`), and the ratios of a trained pair can be changed after training (WiSE-FT's interpolation
between the zero-shot and the adapted features), as `GroundingModel.with_ratios` does.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import cast

import flax.linen as nn
import jax
import jax.numpy as jnp

from ocplace.serial import bounded


@dataclasses.dataclass(frozen=True)
class AdapterConfig:
    dim: int = bounded(512, 1, 8192)  # D, the backbone's embedding width
    reduction: int = bounded(4, 1, 8192)  # hidden width is dim // reduction
    # The weight of the adapter's output in the blend (the text tower's too, unless set).
    residual_ratio: float = bounded(0.2, 0.0, 1.0)
    text_ratio: float | None = bounded(None, 0.0, 1.0)  # the text tower's own weight; None: residual_ratio
    normalise: bool = False  # scale A(x) to the norm of x before the blend (the paper's adapters do not)

    def problems(self) -> list[str]:
        return [] if self.reduction <= self.dim else [f"reduction {self.reduction} is more than dim {self.dim}"]

    @property
    def ratios(self) -> tuple[float, float]:
        """The (visual, text) towers' ratios in the blend."""
        return self.residual_ratio, self.residual_ratio if self.text_ratio is None else self.text_ratio


class ClipAdapter(nn.Module):
    """A(x) = ReLU(W2 ReLU(W1 x)); `(..., D) -> (..., D)`."""

    dim: int
    reduction: int = 4

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        hidden = nn.relu(nn.Dense(self.dim // self.reduction, use_bias=False, name="down")(x))
        return nn.relu(nn.Dense(self.dim, use_bias=False, name="up")(hidden))


def _safe_norm(x: jax.Array) -> jax.Array:
    """`(..., 1)` L2 norm over the last axis, differentiable at zero."""
    return jnp.sqrt(jnp.sum(x * x, axis=-1, keepdims=True) + 1e-12)


def blend(x: jax.Array, adapted: jax.Array, ratio: float, normalise: bool = False) -> jax.Array:
    """`ratio * adapted + (1 - ratio) * x`, `adapted` first scaled to the norm of `x` when `normalise`; with
    ratio 0 this is exactly `x`."""
    if normalise:  # a vanishing A(x) (dead ReLUs, padded tokens) stays at zero, with a finite gradient
        adapted = adapted * _safe_norm(x) / (_safe_norm(adapted) + 1e-6)
    return ratio * adapted + (1.0 - ratio) * x


class GroundingAdapters(nn.Module):
    """The visual and the textual adapter, applied to `(..., T, D)` and `(..., L, D)` tokens."""

    config: AdapterConfig

    @nn.compact
    def __call__(self, visual: jax.Array, text: jax.Array) -> tuple[jax.Array, jax.Array]:
        cfg = self.config
        visual_out = ClipAdapter(cfg.dim, cfg.reduction, name="visual")(visual)
        text_out = ClipAdapter(cfg.dim, cfg.reduction, name="text")(text)
        visual_ratio, text_ratio = cfg.ratios
        return blend(visual, visual_out, visual_ratio, cfg.normalise), blend(text, text_out, text_ratio, cfg.normalise)


@functools.partial(jax.jit, static_argnums=0)  # jitted: eager Flax initialisation is slow
def init_adapters(config: AdapterConfig, key: jax.Array) -> dict:
    """Adapter parameters `{"visual": {...}, "text": {...}}` (Flax's LeCun-normal kernels)."""
    dummy = jnp.zeros((1, config.dim), jnp.float32)
    return GroundingAdapters(config).init(key, dummy, dummy)["params"]


def apply_adapters(
    config: AdapterConfig, params: dict, visual: jax.Array, text: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """`(V*, T*)` for visual tokens `(..., T, D)` and text tokens `(..., L, D)`."""
    adapted = GroundingAdapters(config).apply({"params": params}, visual, text)  # no `mutable`: the output alone
    return cast(tuple[jax.Array, jax.Array], adapted)


def count_parameters(params) -> int:
    return sum(int(leaf.size) for leaf in jax.tree_util.tree_leaves(params))
