"""Tiny randomly initialised CLIP checkpoints, written the way `save_pretrained` writes real ones.

The tokenizer is a byte-level BPE in CLIP's format (vocab.json + merges.txt, `</w>` word ends,
`<|startoftext|>` and `<|endoftext|>` last so the end token has the highest id, as in OpenAI's
vocabulary), with merges learnt by the `tokenizers` package from a small corpus.

`random_clip_params` and `write_clip_tokenizer` also build the benchmarks' towers of real sizes
(`perf/random_clip.py`): no checkpoint is downloaded.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Sequence
from pathlib import Path

import numpy as np

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


def random_clip_params(shapes, seed: int) -> dict:
    """Random CLIP weights for the parameter shapes `shapes` (`model.params_shape_tree`), drawn in numpy.

    transformers' own initialisation runs eagerly (~20 s on CPU even for a tiny model). Kernels are
    LeCun-normal, layer-norm scales near 1, embeddings and biases N(0, 0.02^2), and the logit scale is
    CLIP's initial log(1 / 0.07).
    """
    import jax

    rng = np.random.default_rng(seed)

    def draw(path, leaf):
        name = path[-1].key
        if name == "logit_scale":
            return np.asarray(np.log(1 / 0.07), np.float32)
        if name == "scale":
            return (1.0 + 0.1 * rng.normal(size=leaf.shape)).astype(np.float32)
        std = 1.0 / np.sqrt(np.prod(leaf.shape[:-1])) if name == "kernel" else 0.02  # 0.02: CLIP's init range
        return (std * rng.normal(size=leaf.shape)).astype(np.float32)

    return jax.tree_util.tree_map_with_path(draw, shapes)


def write_clip_tokenizer(directory: Path, merges: Sequence[tuple[str, str]] = ()):
    """A CLIP-format byte-level BPE tokenizer (`vocab.json`, `merges.txt`) written to `directory`, no download.

    The vocabulary is CLIP's byte alphabet,
    the same with `</w>` word ends, the tokens `merges` make, then the start and end tokens last,
    so the end token (also padding and unknown) has the highest id, as in OpenAI's vocabulary.
    """
    from transformers import CLIPTokenizerFast
    from transformers.models.clip.tokenization_clip import bytes_to_unicode

    bos, eos = "<|startoftext|>", "<|endoftext|>"
    chars = list(bytes_to_unicode().values())
    vocab = [*chars, *(c + "</w>" for c in chars)]
    for left, right in merges:
        if left + right not in vocab:
            vocab.append(left + right)
    vocab += [bos, eos]
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    (directory / "vocab.json").write_text(json.dumps({token: i for i, token in enumerate(vocab)}))
    (directory / "merges.txt").write_text("#version: 0.2\n" + "".join(f"{a} {b}\n" for a, b in merges))
    return CLIPTokenizerFast(
        vocab_file=str(directory / "vocab.json"),
        merges_file=str(directory / "merges.txt"),
        bos_token=bos,
        eos_token=eos,
        pad_token=eos,
        unk_token=eos,
    )
