"""Grounding: which of the N + 1 visual tokens each reference phrase names (paper section III-B).

P = softmax over the unmasked visual tokens of `logit_scale * cos(T*, V*)`; the prediction is the
argmax per tuple, index N (the last real token) being the table. Padded visual tokens get a logit
of -inf, so they receive exactly zero probability and zero gradient.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
import optax

from ocplace.models.adapters import AdapterConfig, apply_adapters

_NORM_FLOOR = 1e-12  # keeps padded all-zero tokens finite (and their gradients NaN-free)


def l2_normalize(x: jax.Array) -> jax.Array:
    return x * jax.lax.rsqrt(jnp.maximum(jnp.sum(x * x, axis=-1, keepdims=True), _NORM_FLOOR))


def cosine_logits(text: jax.Array, visual: jax.Array, visual_mask: jax.Array, logit_scale) -> jax.Array:
    """`(..., L, T)` logits `logit_scale * cos(text, visual)`, -inf where `visual_mask` is False.

    text `(..., L, D)`, visual `(..., T, D)`, visual_mask `(..., T)` bool.
    """
    sims = jnp.einsum("...ld,...td->...lt", l2_normalize(text), l2_normalize(visual))
    return jnp.where(visual_mask[..., None, :], logit_scale * sims, -jnp.inf)


def adapted_logits(config: AdapterConfig, params, text, visual, visual_mask, logit_scale) -> jax.Array:
    """Logits after the adapters: `logit_scale * cos(T*, V*)`, shapes as in `cosine_logits`."""
    visual_star, text_star = apply_adapters(config, params, visual, text)
    return cosine_logits(text_star, visual_star, visual_mask, logit_scale)


def grounding_loss(logits: jax.Array, targets: jax.Array, text_mask: jax.Array) -> jax.Array:
    """Mean cross-entropy over the real tuples. logits `(..., L, T)`, targets/text_mask `(..., L)`."""
    per_tuple = optax.softmax_cross_entropy_with_integer_labels(logits, targets)
    per_tuple = jnp.where(text_mask, per_tuple, 0.0)
    return jnp.sum(per_tuple) / jnp.maximum(jnp.sum(text_mask), 1)


def predict(logits: jax.Array) -> jax.Array:
    """`(..., L)` index of the grounded visual token per tuple."""
    return jnp.argmax(logits, axis=-1)


@dataclasses.dataclass(frozen=True)
class GroundingModel:
    """Trained adapters plus what is needed to use them on backbone features."""

    config: AdapterConfig
    params: dict  # {"visual": ..., "text": ...}
    logit_scale: float

    def logits(self, text: np.ndarray, visual: np.ndarray, visual_mask: np.ndarray | None = None) -> np.ndarray:
        """`(..., L, T)` logits for text `(..., L, D)` and visual `(..., T, D)` tokens."""
        if visual_mask is None:
            visual_mask = np.ones(np.shape(visual)[:-1], bool)
        return np.asarray(_jitted_logits(self.config, self.params, text, visual, visual_mask, self.logit_scale))

    def probabilities(self, text, visual, visual_mask=None) -> np.ndarray:
        """`(..., L, T)` P: a distribution over the visual tokens per tuple."""
        return np.asarray(jax.nn.softmax(self.logits(text, visual, visual_mask), axis=-1))

    def with_ratios(self, visual: float, text: float) -> GroundingModel:
        """The same trained adapters blended with other ratios (visual, text): WiSE-FT's interpolation between
        the zero-shot features (0) and the adapted ones, chosen after training."""
        return dataclasses.replace(
            self, config=dataclasses.replace(self.config, residual_ratio=visual, text_ratio=text)
        )

    @classmethod
    def zero_shot(cls, dim: int, logit_scale: float) -> GroundingModel:
        """Plain CLIP similarity: residual ratio 0, so the adapters are bypassed exactly."""
        from ocplace.models.adapters import init_adapters

        config = AdapterConfig(dim=dim, residual_ratio=0.0)
        params = jax.tree_util.tree_map(jnp.zeros_like, init_adapters(config, jax.random.key(0)))
        return cls(config, params, logit_scale)


@functools.partial(jax.jit, static_argnums=0)
def _jitted_logits(config, params, text, visual, visual_mask, logit_scale):
    return adapted_logits(config, params, text, visual, visual_mask, logit_scale)
