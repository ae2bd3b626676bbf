"""CLIP-Adapters (Gao et al.): a small bottleneck MLP blended residually into frozen CLIP features.

A(x) = ReLU(W2 ReLU(W1 x)) with W1: D -> D/reduction and W2: D/reduction -> D, no biases, and
x* = ratio * A(x) + (1 - ratio) * x. One adapter for the visual tokens, one for the text tokens;
for D = 512 and reduction 4 the pair has 2 * 2 * 512 * 128 = 262,144 parameters.
"""

from __future__ import annotations

import dataclasses
import functools

import flax.linen as nn
import jax
import jax.numpy as jnp


@dataclasses.dataclass(frozen=True)
class AdapterConfig:
    dim: int = 512  # D, the backbone's embedding width
    reduction: int = 4  # hidden width is dim // reduction
    residual_ratio: float = 0.2  # weight of the adapter's output in the blend


class ClipAdapter(nn.Module):
    """A(x) = ReLU(W2 ReLU(W1 x)); `(..., D) -> (..., D)`."""

    dim: int
    reduction: int = 4

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        hidden = nn.relu(nn.Dense(self.dim // self.reduction, use_bias=False, name="down")(x))
        return nn.relu(nn.Dense(self.dim, use_bias=False, name="up")(hidden))


def blend(x: jax.Array, adapted: jax.Array, ratio: float) -> jax.Array:
    """`ratio * adapted + (1 - ratio) * x`; with ratio 0 this is exactly `x`."""
    return ratio * adapted + (1.0 - ratio) * x


class GroundingAdapters(nn.Module):
    """The visual and the textual adapter, applied to `(..., T, D)` and `(..., L, D)` tokens."""

    config: AdapterConfig

    @nn.compact
    def __call__(self, visual: jax.Array, text: jax.Array) -> tuple[jax.Array, jax.Array]:
        cfg = self.config
        visual_out = ClipAdapter(cfg.dim, cfg.reduction, name="visual")(visual)
        text_out = ClipAdapter(cfg.dim, cfg.reduction, name="text")(text)
        return blend(visual, visual_out, cfg.residual_ratio), blend(text, text_out, cfg.residual_ratio)


@functools.partial(jax.jit, static_argnums=0)  # jitted: eager Flax initialisation is slow
def init_adapters(config: AdapterConfig, key: jax.Array) -> dict:
    """Adapter parameters `{"visual": {...}, "text": {...}}` (Flax's LeCun-normal kernels)."""
    dummy = jnp.zeros((1, config.dim), jnp.float32)
    return GroundingAdapters(config).init(key, dummy, dummy)["params"]


def apply_adapters(
    config: AdapterConfig, params: dict, visual: jax.Array, text: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """`(V*, T*)` for visual tokens `(..., T, D)` and text tokens `(..., L, D)`."""
    return GroundingAdapters(config).apply({"params": params}, visual, text)


def count_parameters(params) -> int:
    return sum(int(leaf.size) for leaf in jax.tree_util.tree_leaves(params))
