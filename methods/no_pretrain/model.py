"""Ours w/o CLIP pre-train: Ours' backbone architecture at random initialisation, trained with the
CLIP-Adapters end to end on the grounding loss of the training split alone.

The analogue of the paper's ablation: no ImageNet weights and no contrastive pretraining, the
same EfficientNet-Lite trunk, input size and trained part as Ours (`default_config`). Trained: the
trunk's blocks after `frozen_blocks` (Ours fine-tunes the same ones), its projection, the text
projection, the temperature and both adapters. Frozen: the trunk's first blocks at their random
initialisation (training the whole trunk from scratch costs ~3x more on a CPU) and the MiniLM
sentence encoder under the text projection (the offline backbone locks it too), so the ablation
removes pretraining, not language.
Once trained, the tower is an ordinary `OfflineBackbone` and the adapters an ordinary
`GroundingModel`: grounding at test time is Ours' code path on these weights.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from ocplace.methods.no_pretrain.recipe import NoPretrainConfig
from ocplace.models import efficientnet
from ocplace.models import offline_backbone as ob
from ocplace.models.adapters import apply_adapters, init_adapters
from ocplace.models.grounding import cosine_logits, grounding_loss

BACKBONE_DIR = "backbone"  # the trained tower inside a run directory, an offline backbone directory


def init_params(config: NoPretrainConfig, key) -> dict:
    """`{"backbone": offline backbone params, "adapters": {"visual", "text"}}`."""
    backbone_key, adapter_key = jax.random.split(key)
    return {
        "backbone": ob.init_params(config.backbone, backbone_key),
        "adapters": init_adapters(config.adapters, adapter_key),
    }


CALIBRATION_IMAGES = 256


def calibrate(config: NoPretrainConfig, backbone: dict, arrays: dict) -> dict:
    """Backbone params whose random EfficientNet trunk has its batch-norm statistics measured on the
    first `CALIBRATION_IMAGES` real visual tokens of the training inputs (`arrays["pixels"]
    (n, T, S, S, 3)`, `arrays["visual_mask"] (n, T)`); other backbones unchanged."""
    if config.backbone.is_vit or config.backbone.trunk_init != "random":
        return backbone
    pixels = np.asarray(arrays["pixels"])[np.asarray(arrays["visual_mask"], bool)][:CALIBRATION_IMAGES]
    vision = efficientnet.calibrate_batch_stats(backbone["vision"], pixels, config.backbone.trunk)
    return {**backbone, "vision": jax.tree_util.tree_map(np.asarray, vision)}


def trainable_mask(config: NoPretrainConfig, params: dict) -> dict:
    """Bools over `params`: the backbone's `ob.trainable_mask`, every adapter weight."""
    return {
        "backbone": ob.trainable_mask(config.backbone, params["backbone"]),
        "adapters": jax.tree_util.tree_map(lambda _: True, params["adapters"]),
    }


def dihedral(pixels, codes):
    """One of the 8 symmetries of the square per image: pixels `(B, S, S, 3)`, codes int `(B,)` in 0..7.

    The camera looks straight down, so a quarter turn or a mirror image of a crop is a pose the
    benchmark can show.
    """

    def pick(bit, transformed, image):
        return jnp.where(((codes >> bit) & 1).astype(bool)[:, None, None, None], transformed, image)

    pixels = pick(0, jnp.swapaxes(pixels, 1, 2), pixels)
    pixels = pick(1, pixels[:, ::-1], pixels)
    return pick(2, pixels[:, :, ::-1], pixels)


def logit_scale(config: NoPretrainConfig, params: dict):
    return jnp.exp(jnp.minimum(params["backbone"]["log_logit_scale"], math.log(config.max_logit_scale)))


def grounding_logits(config: NoPretrainConfig, params: dict, pixels, visual_mask, sentences):
    """`(B, K, T)` adapted logits.

    pixels uint8 `(B, T, S, S, 3)` preprocessed images (crops, then the workspace, then padding),
    visual_mask `(B, T)`, sentences `(B, K, 384)` frozen MiniLM embeddings of the prompted phrases.
    """
    batch, tokens = pixels.shape[:2]
    visual = ob.image_embeddings(config.backbone, params["backbone"], pixels.reshape(batch * tokens, *pixels.shape[2:]))
    visual = visual.reshape(batch, tokens, -1)
    text = ob.text_embeddings(params["backbone"], sentences)
    visual_star, text_star = apply_adapters(config.adapters, params["adapters"], visual, text)
    return cosine_logits(text_star, visual_star, visual_mask, logit_scale(config, params))


def loss(config: NoPretrainConfig, params: dict, batch: dict, codes):
    """Ours' grounding loss; `codes` int `(B, T)` picks each image's symmetry (all 0: no augmentation)."""
    pixels = batch["pixels"]
    flat = dihedral(pixels.reshape(-1, *pixels.shape[2:]), codes.reshape(-1)).reshape(pixels.shape)
    logits = grounding_logits(config, params, flat, batch["visual_mask"], batch["sentences"])
    return grounding_loss(logits, batch["targets"], batch["text_mask"])
