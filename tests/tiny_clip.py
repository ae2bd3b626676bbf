"""Tiny randomly initialised CLIP checkpoints, written the way `save_pretrained` writes real ones.

The tokenizer is a byte-level BPE in CLIP's format (vocab.json + merges.txt, `</w>` word ends,
`<|startoftext|>` and `<|endoftext|>` last so the end token has the highest id, as in OpenAI's
vocabulary), with merges learnt by the `tokenizers` package from a small corpus.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np

from ocplace.models.backbone import random_clip_params, write_clip_tokenizer

CORPUS = (
    "a photo of a red bowl.",
    "a photo of a blue mug.",
    "a photo of a table.",
    "a photo of a black shoe.",
    "a photo of a spiderman figure.",
    "a photo of a green apple.",
    "a photo of a yellow banana.",
    "a photo of a white plate.",
    "a photo of a wooden block.",
    "put it to the left of the bowl.",
    "put it behind the mug and in front of the shoe.",
    "the thing on the table.",
)
FORMATS = ("flax-msgpack", "flax-safetensors", "pt-safetensors")


def train_merges(corpus=CORPUS, num_merges: int = 120) -> list[tuple[str, str]]:
    """BPE merges learnt with CLIP's normaliser and pre-tokeniser."""
    from tokenizers import Regex, Tokenizer, models, normalizers, pre_tokenizers, trainers

    tokenizer = Tokenizer(models.BPE(end_of_word_suffix="</w>", continuing_subword_prefix=""))
    tokenizer.normalizer = normalizers.Sequence(
        [normalizers.NFC(), normalizers.Replace(Regex(r"\s+"), " "), normalizers.Lowercase()]
    )
    tokenizer.pre_tokenizer = pre_tokenizers.Sequence(
        [
            pre_tokenizers.Split(
                Regex(r"""'s|'t|'re|'ve|'m|'ll|'d|[\p{L}]+|[\p{N}]|[^\s\p{L}\p{N}]+"""), behavior="removed", invert=True
            ),
            pre_tokenizers.ByteLevel(add_prefix_space=False),
        ]
    )
    alphabet = pre_tokenizers.ByteLevel.alphabet()
    trainer = trainers.BpeTrainer(
        vocab_size=2 * len(alphabet) + num_merges,
        initial_alphabet=alphabet,
        end_of_word_suffix="</w>",
        show_progress=False,
    )
    tokenizer.train_from_iterator(corpus, trainer)
    merges = json.loads(tokenizer.to_str())["model"]["merges"]
    return [tuple(m.split(" ")) if isinstance(m, str) else tuple(m) for m in merges]


def write_tokenizer(directory: Path, corpus=CORPUS):
    """CLIP-format tokenizer files in `directory`, with merges learnt from `corpus`; returns the fast tokenizer."""
    tokenizer = write_clip_tokenizer(directory, train_merges(corpus))
    tokenizer.save_pretrained(directory)
    return tokenizer


def tiny_config(
    vocab_size: int,
    bos_id: int,
    eos_id: int,
    image_size: int = 32,
    width: int = 32,
    projection_dim: int = 16,
    layers: int = 2,
    context_length: int = 16,
):
    from transformers import CLIPConfig

    text = dict(
        vocab_size=vocab_size,
        hidden_size=width,
        intermediate_size=2 * width,
        num_hidden_layers=layers,
        num_attention_heads=2,
        max_position_embeddings=context_length,
        bos_token_id=bos_id,
        eos_token_id=eos_id,
        pad_token_id=eos_id,
    )
    vision = dict(
        image_size=image_size,
        patch_size=image_size // 4,
        hidden_size=width,
        intermediate_size=2 * width,
        num_hidden_layers=layers,
        num_attention_heads=2,
    )
    return CLIPConfig(text_config=text, vision_config=vision, projection_dim=projection_dim)


def build_tiny_clip(
    directory: Path,
    seed: int = 0,
    weights: str = "flax-msgpack",
    image_size: int = 32,
    tokenizer_dir: Path | None = None,
    **config_kwargs,
) -> Path:
    """A complete CLIP checkpoint directory with random weights; `weights` is one of FORMATS.

    BPE training breaks frequency ties arbitrarily, so checkpoints meant to share a tokenizer copy
    it from `tokenizer_dir` (written by `write_tokenizer`) instead of training their own.
    """
    from transformers import CLIPImageProcessor, CLIPTokenizerFast, FlaxCLIPModel

    directory = Path(directory)
    if tokenizer_dir is None:
        tokenizer = write_tokenizer(directory)
    else:
        shutil.copytree(tokenizer_dir, directory, dirs_exist_ok=True)
        tokenizer = CLIPTokenizerFast.from_pretrained(directory)
    config = tiny_config(
        len(tokenizer), tokenizer.bos_token_id, tokenizer.eos_token_id, image_size=image_size, **config_kwargs
    )
    model = FlaxCLIPModel(config, _do_init=False)
    params = random_clip_params(model.params_shape_tree, seed)
    if weights == "pt-safetensors":
        config.save_pretrained(directory)
        save_as_pytorch_safetensors(params, directory / "model.safetensors")
    else:
        model.save_pretrained(directory, params=params, safe_serialization=weights == "flax-safetensors")
    CLIPImageProcessor(
        size={"shortest_edge": image_size}, crop_size={"height": image_size, "width": image_size}
    ).save_pretrained(directory)
    return directory


def save_as_pytorch_safetensors(params, path: Path) -> None:
    """Flax CLIP params written under PyTorch's names and layouts, as a torch checkpoint would be."""
    from flax.traverse_util import flatten_dict
    from safetensors.numpy import save_file

    tensors = {}
    for key, value in flatten_dict(params).items():
        value = np.asarray(value)
        *prefix, leaf = key
        if leaf == "kernel":
            value = value.transpose(3, 2, 0, 1) if value.ndim == 4 else value.T
        if leaf in ("kernel", "scale", "embedding"):
            leaf = "weight"
        tensors[".".join([*prefix, leaf])] = np.array(value, order="C")  # keeps 0-d shapes
    save_file(tensors, str(path), metadata={"format": "pt"})
