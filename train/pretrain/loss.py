"""Symmetric InfoNCE with label-aware positives (pure, jit-able)."""

from __future__ import annotations

import optax


def contrastive_loss(image_embeddings, text_embeddings, positives, logit_scale):
    """CLIP's symmetric loss where a caption may describe several images of the batch.

    image_embeddings `(B, D)` and text_embeddings `(T, D)` unit rows; positives bool `(B, T)`,
    True where caption t describes image b (every row and column holds at least one True).
    Each direction's target is uniform over the positives, so a repeated object, or a caption
    such as "a bowl" shared by several objects, is never pushed away from its own images.
    """
    logits = logit_scale * image_embeddings @ text_embeddings.T
    positives = positives.astype(logits.dtype)
    image_to_text = optax.softmax_cross_entropy(logits, positives / positives.sum(axis=1, keepdims=True))
    text_to_image = optax.softmax_cross_entropy(logits.T, positives.T / positives.T.sum(axis=1, keepdims=True))
    return 0.5 * (image_to_text.mean() + text_to_image.mean())
