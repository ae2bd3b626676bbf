"""Flax CLIP models of real sizes with random weights, for the benchmarks: nothing is downloaded.

A random tower costs what a trained one of the same sizes costs. Imported by the scripts beside it
(`perf/featurize.py`, `perf/policy.py`), which run with `perf/` on `sys.path`.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))  # the test support builds CLIP towers
from tiny_clip import random_clip_params, write_clip_tokenizer

from ocplace.models.backbone import ClipBackbone, ImagePreprocessing
from ocplace.vocabulary import CLIP_IMAGE_MEAN, CLIP_IMAGE_STD

# openai/clip-vit-base-patch32's architecture.
VIT_B32 = dict(
    text_config=dict(
        hidden_size=512,
        intermediate_size=2048,
        num_hidden_layers=12,
        num_attention_heads=8,
        max_position_embeddings=77,
        vocab_size=49408,
    ),
    vision_config=dict(
        image_size=224,
        patch_size=32,
        hidden_size=768,
        intermediate_size=3072,
        num_hidden_layers=12,
        num_attention_heads=12,
    ),
    projection_dim=512,
)
TINY_CLIP = dict(
    text_config=dict(
        hidden_size=32,
        intermediate_size=64,
        num_hidden_layers=2,
        num_attention_heads=2,
        max_position_embeddings=16,
        vocab_size=49408,
    ),
    vision_config=dict(
        image_size=32, patch_size=8, hidden_size=32, intermediate_size=64, num_hidden_layers=2, num_attention_heads=2
    ),
    projection_dim=16,
)


def clip_preprocessing(sizes: dict) -> ImagePreprocessing:
    """CLIP's preprocessing at the vision tower's input size of `sizes`."""
    size = sizes["vision_config"]["image_size"]
    return ImagePreprocessing(size, (size, size), CLIP_IMAGE_MEAN, CLIP_IMAGE_STD, resample=3)


def random_clip_model(sizes: dict, **text_ids):
    """`(FlaxCLIPModel, params)` of `sizes` with random weights; `text_ids` set the text config's token ids."""
    from transformers import CLIPConfig, FlaxCLIPModel

    config = CLIPConfig(
        text_config={**sizes["text_config"], **text_ids},
        vision_config=sizes["vision_config"],
        projection_dim=sizes["projection_dim"],
    )
    model = FlaxCLIPModel(config, _do_init=False)
    return model, random_clip_params(model.params_shape_tree, seed=0)


def random_clip_backbone(sizes: dict, directory: Path) -> ClipBackbone:
    """A Flax CLIP of `sizes` with random weights and a byte-level tokenizer with no merges written to `directory`.

    Texts are padded to the model's context length, so the text tower costs what it costs with
    OpenAI's 49,408-token vocabulary.
    """
    tokenizer = write_clip_tokenizer(directory)
    model, params = random_clip_model(
        sizes,
        bos_token_id=tokenizer.bos_token_id,
        eos_token_id=tokenizer.eos_token_id,
        pad_token_id=tokenizer.eos_token_id,
    )
    return ClipBackbone(model, params, tokenizer, clip_preprocessing(sizes), source="random")
