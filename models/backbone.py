"""Frozen vision-language backbones: the `Backbone` interface and transformers' Flax CLIP.

A backbone maps uint8 images and strings into one L2-normalised embedding space of width `dim`.
Its `fingerprint` changes whenever anything that changes an embedding changes (weights, model
config, tokenizer, image preprocessing), so feature caches keyed by it never go stale.

Backbone specs (`--backbone SPEC` on the command line, `load_backbone(spec)` in code):
`KIND:ARGUMENT` or a bare `KIND` (the same as `KIND:`), for each kind in `BACKBONE_LOADERS`:
`offline` is the default recipe's offline backbone, `offline:demo` another recipe's,
`offline:/path/to/dir` a saved one; `clip:NAME_OR_DIR` (or just `NAME_OR_DIR`) loads a CLIP
checkpoint, either a Hugging Face hub id such as `openai/clip-vit-base-patch32` or a local directory.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import importlib
import json
import os
import socket
import urllib.parse
from collections.abc import Sequence
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np

from ocplace.errors import BackboneError, BackboneUnavailable
from ocplace.models.preprocessing import ImagePreprocessing
from ocplace.vocabulary import PLURAL_NOUNS

DEFAULT_CLIP = "openai/clip-vit-base-patch32"
# kind -> "module:function(argument: str) -> Backbone"; the offline backbone adds its own kind.
BACKBONE_LOADERS = {
    "clip": "ocplace.models.backbone:load_clip_backbone",
    "offline": "ocplace.models.offline_backbone:load_offline_backbone",
    "policy": "ocplace.models.policy_folder:load_folder_backbone",  # `offline:DIR` of a policy folder, too
}
POLICY_WEIGHTS_FILE = "model.safetensors"  # what marks a policy folder (`ocplace export`), not a saved backbone
_HUB_PROBE_TIMEOUT_S = 3.0


@runtime_checkable
class Backbone(Protocol):
    """What grounding needs from a vision-language model."""

    @property
    def dim(self) -> int: ...

    @property
    def fingerprint(self) -> str:
        """Hex digest that changes whenever an embedding could change."""

    @property
    def logit_scale(self) -> float:
        """The temperature the backbone was trained with (CLIP: exp(learned), 100 for OpenAI's)."""

    def encode_images(self, images: np.ndarray) -> np.ndarray:
        """uint8 `(B, H, W, 3)` RGB -> float32 `(B, D)`, each row of unit norm."""

    def encode_texts(self, texts: Sequence[str]) -> np.ndarray:
        """`L` strings -> float32 `(L, D)`, each row of unit norm."""


@dataclasses.dataclass(frozen=True)
class PromptConfig:
    """How a reference phrase becomes the text given to the text tower.

    CLIP was trained on captions, so a bare noun phrase ("red bowl") embeds less reliably than a
    caption; "a photo of a {}." is the prompt CLIP's authors use for zero-shot classification.
    The table token is the whole workspace image, so the table phrase gets the same template.
    """

    template: str = "a photo of a {}."
    table_phrases: tuple[str, ...] = ("table", "the table")
    table_text: str = "a photo of a table."

    def problems(self) -> list[str]:
        braces = self.template.count("{") + self.template.count("}")
        if self.template.count("{}") != 1 or braces != 2:
            return [f"template {self.template!r} must hold one {{}} (where the phrase goes) and no other brace"]
        return []

    def text_for(self, phrase: str, plural: bool = True) -> str:
        """The caption of `phrase`; a plural object ("scissors", "black sneakers") loses the template's "a ", unless
        `plural` is off (the offline backbone's pretraining captions, which its recipe key names, keep it)."""
        phrase = " ".join(phrase.split())
        if phrase.lower() in self.table_phrases:
            return self.table_text
        if plural and is_plural(phrase) and "a {}" in self.template:
            return self.template.replace("a {}", "{}", 1).format(phrase)
        return self.template.format(phrase)


def is_plural(phrase: str) -> bool:
    """Whether the phrase's head noun (its last word before "with", "of", ...) is one of `PLURAL_NOUNS`."""
    words = phrase.lower().split()
    for index, word in enumerate(words):
        if word in ("with", "of", "for", "on", "in") and index > 0:
            words = words[:index]
            break
    return bool(words) and words[-1] in PLURAL_NOUNS


def load_backbone(spec: str, **kwargs) -> Backbone:
    """A backbone from a spec string (see the module docstring); a bare kind such as "offline" is "offline:"."""
    kind, _, argument = spec.partition(":")
    if kind == "offline" and argument and (Path(argument).expanduser() / POLICY_WEIGHTS_FILE).is_file():
        kind = "policy"  # an exported policy folder holds its backbone (out/demo/policy)
    if kind in BACKBONE_LOADERS:
        module_name, _, function_name = BACKBONE_LOADERS[kind].partition(":")
        return getattr(importlib.import_module(module_name), function_name)(argument, **kwargs)
    if "/" not in spec and not Path(spec).is_dir():
        raise BackboneError(
            f"unknown backbone {spec!r}: use clip:HUB_ID, clip:/path/to/clip_dir or a local CLIP "
            f"directory; registered kinds: {sorted(BACKBONE_LOADERS)}"
        )
    return load_clip_backbone(spec, **kwargs)


# ----------------------------------------------------------------------------- image preprocessing


def resize_and_crop(image: np.ndarray, prep: ImagePreprocessing) -> np.ndarray:
    """uint8 `(H, W, 3)` -> uint8 `(crop_h, crop_w, 3)`, bit-identical to CLIPImageProcessor's steps."""
    from PIL import Image

    height, width = image.shape[:2]
    short, long = sorted((height, width))
    new_long = int(prep.resize * long / short)  # truncation, as transformers does
    new_h, new_w = (new_long, prep.resize) if width <= height else (prep.resize, new_long)
    resized = np.asarray(Image.fromarray(image).resize((new_w, new_h), resample=prep.resample))
    crop_h, crop_w = prep.crop
    if crop_h > new_h or crop_w > new_w:
        raise BackboneError(f"crop {prep.crop} larger than the resized image {(new_h, new_w)}")
    top, left = (new_h - crop_h) // 2, (new_w - crop_w) // 2
    return resized[top : top + crop_h, left : left + crop_w]


def normalize_pixels(pixels, prep: ImagePreprocessing):
    """uint8 `(B, h, w, 3)` -> float32 `(B, 3, h, w)`, the channels-first layout Flax CLIP expects."""
    import jax.numpy as jnp

    scaled = pixels.astype(jnp.float32) * jnp.float32(1.0 / 255.0)
    normalized = (scaled - jnp.asarray(prep.mean, jnp.float32)) / jnp.asarray(prep.std, jnp.float32)
    return jnp.transpose(normalized, (0, 3, 1, 2))


def check_images(images: np.ndarray) -> np.ndarray:
    images = np.asarray(images)
    if images.dtype != np.uint8 or images.ndim != 4 or images.shape[-1] != 3:
        raise BackboneError(f"images must be uint8 (B, H, W, 3) RGB, got {images.dtype} {images.shape}")
    return images


# ----------------------------------------------------------------------------- batching


def bucket_size(count: int, max_batch: int) -> int:
    """The smallest of 1, 2, 3, 4, 6, 8, 12, 16, ... (2^k and 3 * 2^k) >= count, capped at max_batch.

    Few shapes, so few compilations; at most a third of a batch is padding (a scene's 5 crops and
    its workspace image are one batch of 6, not 8).
    """
    power = 1 << max(count - 1, 0).bit_length()
    return min(max_batch, power * 3 // 4 if power * 3 // 4 >= count else power)


def run_batched(fn, arrays: tuple[np.ndarray, ...], max_batch: int) -> np.ndarray:
    """`fn(*batch)` over chunks of at most `max_batch` rows, zero-padded to a bucket size."""
    total = len(arrays[0])
    outputs = []
    for start in range(0, total, max_batch):
        chunk = [a[start : start + max_batch] for a in arrays]
        count = len(chunk[0])
        size = bucket_size(count, max_batch)
        padded = [np.concatenate([c, np.zeros((size - count, *c.shape[1:]), c.dtype)]) for c in chunk]
        outputs.append(np.asarray(fn(*padded))[:count])
    return np.concatenate(outputs)


# ----------------------------------------------------------------------------- CLIP


class ClipBackbone:
    """transformers' `FlaxCLIPModel` with CLIP's own tokenizer and image preprocessing, jitted."""

    def __init__(self, model, params, tokenizer, prep: ImagePreprocessing, source: str, max_batch: int = 32):
        import jax

        self._model, self._params, self._tokenizer = model, jax.device_put(params), tokenizer
        self.preprocessing, self.source, self.max_batch = prep, source, max_batch
        self.context_length = model.config.text_config.max_position_embeddings
        self._image_fn = jax.jit(self._image_features)
        self._text_fn = jax.jit(self._text_features)

    @property
    def dim(self) -> int:
        return int(self._model.config.projection_dim)

    @property
    def logit_scale(self) -> float:
        return float(np.exp(np.asarray(self._params["logit_scale"])))

    @functools.cached_property
    def fingerprint(self) -> str:
        digest = hashlib.sha256(b"ocplace-clip-backbone-v1")
        digest.update(_config_json(self._model.config).encode())
        digest.update(json.dumps(dataclasses.asdict(self.preprocessing), sort_keys=True).encode())
        digest.update(_tokenizer_json(self._tokenizer).encode())
        digest.update(str(self.context_length).encode())
        update_with_params(digest, self._params)
        return digest.hexdigest()

    def encode_images(self, images: np.ndarray) -> np.ndarray:
        images = check_images(images)
        if len(images) == 0:
            return np.zeros((0, self.dim), np.float32)
        pixels = np.stack([resize_and_crop(image, self.preprocessing) for image in images])
        return run_batched(lambda p: self._image_fn(self._params, p), (pixels,), self.max_batch)

    def encode_texts(self, texts: Sequence[str]) -> np.ndarray:
        texts = list(texts)
        if not texts:
            return np.zeros((0, self.dim), np.float32)
        tokens = self._tokenizer(
            texts, padding="longest", max_length=self.context_length, truncation=True, return_tensors="np"
        )
        ids, mask = tokens["input_ids"].astype(np.int32), tokens["attention_mask"].astype(np.int32)
        # Tuple texts are a dozen tokens: padding them to the context length (77) would make the
        # text tower 6x slower. Causal attention keeps the pooled token blind to the padding.
        padding = ((0, 0), (0, bucket_size(ids.shape[1], self.context_length) - ids.shape[1]))
        ids = np.pad(ids, padding, constant_values=self._tokenizer.pad_token_id)
        mask = np.pad(mask, padding)
        return run_batched(lambda i, m: self._text_fn(self._params, i, m), (ids, mask), self.max_batch)

    def _image_features(self, params, pixels):
        from ocplace.models.grounding import l2_normalize

        features = self._model.get_image_features(normalize_pixels(pixels, self.preprocessing), params=params)
        return l2_normalize(features)

    def _text_features(self, params, input_ids, attention_mask):
        from ocplace.models.grounding import l2_normalize

        return l2_normalize(self._model.get_text_features(input_ids, attention_mask, params=params))


def _tokenizer_json(tokenizer) -> str:
    """The tokenizer's vocabulary and rules, without the padding and truncation state that calls set."""
    fields = json.loads(tokenizer.backend_tokenizer.to_str())
    fields.pop("padding", None)
    fields.pop("truncation", None)
    return json.dumps(fields, sort_keys=True)


def _config_json(config) -> str:
    """The model config (transformers' `PretrainedConfig`) without bookkeeping fields that do not change the model."""
    fields = config.to_dict()
    for key in ("architectures", "_name_or_path", "transformers_version", "torch_dtype", "dtype", "_commit_hash"):
        fields.pop(key, None)
    return json.dumps(fields, sort_keys=True, default=str)


def update_with_params(digest, params) -> None:
    """Feeds every leaf's path, dtype, shape and bytes into `digest`, in a fixed order."""
    import jax

    leaves = jax.tree_util.tree_leaves_with_path(params)
    for path, leaf in sorted(leaves, key=lambda item: jax.tree_util.keystr(item[0])):
        array = np.array(leaf, order="C")
        digest.update(f"{jax.tree_util.keystr(path)}|{array.dtype}|{array.shape}".encode())
        digest.update(array.tobytes())


def load_clip_backbone(name_or_dir: str = DEFAULT_CLIP, max_batch: int = 32, cached_only: bool = False) -> ClipBackbone:
    """A CLIP checkpoint from a local directory or the Hugging Face hub (cache first).

    Local directories may hold Flax weights (`flax_model.msgpack`, or `model.safetensors` saved by
    Flax) or PyTorch weights in `model.safetensors`; transformers converts the latter without torch.
    Without a network and without a cached copy this raises `BackboneUnavailable` at once instead
    of retrying. An empty name (the spec `clip` or `clip:`) is `DEFAULT_CLIP`.
    """
    name_or_dir = name_or_dir or DEFAULT_CLIP
    local = Path(name_or_dir).expanduser()
    if local.is_dir():
        check_clip_folder(local)
        try:
            return _load_clip(str(local), local_only=True, max_batch=max_batch)
        except (OSError, ValueError, TypeError) as error:
            raise BackboneError(
                f"{local} holds a CLIP checkpoint that does not load ({error}); {_WRITE_CLIP}"
            ) from None
    if looks_like_path(name_or_dir):
        raise BackboneUnavailable(f"no CLIP directory at {local}. {_how_to_fix()}")
    try:
        return _load_clip(name_or_dir, local_only=True, max_batch=max_batch)
    except OSError:
        pass  # not in the Hugging Face cache
    if cached_only:  # a hub id read from a file the user did not write: never a download
        raise BackboneUnavailable(
            f"CLIP checkpoint {name_or_dir!r} is not in the Hugging Face cache, and a hub id a policy folder names is "
            "never downloaded on its own: download it yourself, or pass the checkpoint (`checkpoint=` / `--backbone`)"
        )
    if os.environ.get("HF_HUB_OFFLINE", "0").lower() in ("1", "true", "yes"):
        raise BackboneUnavailable(
            f"CLIP checkpoint {name_or_dir!r} is not in the Hugging Face cache and HF_HUB_OFFLINE is set. "
            f"{_how_to_fix()}"
        )
    host = _hub_host()
    if not _reachable(host):
        raise BackboneUnavailable(
            f"cannot load CLIP checkpoint {name_or_dir!r}: {host[0]} is unreachable (no network) and there is "
            f"no local copy in the Hugging Face cache. {_how_to_fix()}"
        )
    try:
        return _load_clip(name_or_dir, local_only=False, max_batch=max_batch)
    except OSError as error:
        raise BackboneUnavailable(f"cannot load CLIP checkpoint {name_or_dir!r}: {error}. {_how_to_fix()}") from error


# What a local CLIP checkpoint folder needs: (what it is, the files of which any one will do).
CLIP_FILES = (
    ("the model's config", ("config.json",)),
    ("the weights", ("flax_model.msgpack", "model.safetensors")),
    ("the tokenizer", ("tokenizer.json", "vocab.json")),
    ("the image preprocessing", ("preprocessor_config.json",)),
)
_WRITE_CLIP = (
    "write a complete folder with `FlaxCLIPModel.from_pretrained(ID).save_pretrained(DIR)` (config and weights; "
    "a PyTorch `CLIPModel` writes a model.safetensors ocplace converts) and `CLIPProcessor.from_pretrained(ID)"
    ".save_pretrained(DIR)` (tokenizer and preprocessor_config.json)"
)


def check_clip_folder(folder: Path) -> None:
    """BackboneError naming every file a local CLIP checkpoint folder lacks, and how to write them."""
    missing = [
        f"{what} ({' or '.join(names)})" for what, names in CLIP_FILES if not any((folder / n).is_file() for n in names)
    ]
    if (folder / "vocab.json").is_file() and not (folder / "tokenizer.json").is_file():
        missing += [] if (folder / "merges.txt").is_file() else ["the tokenizer's merges (merges.txt)"]
    if missing:
        raise BackboneError(f"{folder} is not a complete CLIP checkpoint: it lacks {'; '.join(missing)}; {_WRITE_CLIP}")


def _load_clip(name_or_dir: str, local_only: bool, max_batch: int) -> ClipBackbone:
    from transformers import CLIPImageProcessor, CLIPTokenizerFast

    model, params = _load_flax_clip(name_or_dir, local_only)
    tokenizer = CLIPTokenizerFast.from_pretrained(name_or_dir, local_files_only=local_only)
    processor = CLIPImageProcessor.from_pretrained(name_or_dir, local_files_only=local_only)
    return ClipBackbone(
        model, params, tokenizer, ImagePreprocessing.from_processor(processor), source=name_or_dir, max_batch=max_batch
    )


def _load_flax_clip(name_or_dir: str, local_only: bool):
    """`(model, params)` without a random initialisation first (eager init takes ~20 s on CPU).

    transformers only converts PyTorch weights into an initialised model, so PyTorch-format
    `model.safetensors` files in a local directory are converted here against the parameter shapes.
    """
    from transformers import CLIPConfig, FlaxCLIPModel

    weights = Path(name_or_dir) / "model.safetensors"
    if not _is_pytorch_safetensors(weights) or (Path(name_or_dir) / "flax_model.msgpack").exists():
        return FlaxCLIPModel.from_pretrained(name_or_dir, local_files_only=local_only, _do_init=False)
    import types

    import jax
    from transformers.modeling_flax_pytorch_utils import load_pytorch_checkpoint_in_flax_state_dict

    model = FlaxCLIPModel(CLIPConfig.from_pretrained(name_or_dir), _do_init=False)
    shapes = types.SimpleNamespace(params=model.params_shape_tree, base_model_prefix=model.base_model_prefix)
    params = load_pytorch_checkpoint_in_flax_state_dict(shapes, str(weights), is_sharded=False)
    if str(jax.tree_util.tree_structure(params)) != str(jax.tree_util.tree_structure(model.params_shape_tree)):
        raise BackboneError(f"{weights} does not hold every weight of the CLIP model its config.json describes")
    return model, params


def _is_pytorch_safetensors(path: Path) -> bool:
    if not path.is_file():
        return False
    from safetensors import safe_open

    with safe_open(str(path), framework="numpy") as handle:
        return (handle.metadata() or {}).get("format") == "pt"


def looks_like_path(name: str) -> bool:
    """Whether a CLIP spec's argument names a local folder rather than a hub id (`org/name`)."""
    return name.startswith((".", "~", os.sep)) or name.count("/") > 1


def _how_to_fix() -> str:
    return (
        "Pass a local directory holding a CLIP checkpoint (config.json, flax_model.msgpack or "
        "model.safetensors, tokenizer and preprocessor_config.json files), e.g. "
        "`--backbone clip:/path/to/clip-vit-base-patch32`, or choose the offline backbone "
        "(`--backbone offline`)."
    )


def _hub_host() -> tuple[str, int]:
    from huggingface_hub import constants

    proxy = os.environ.get("HTTPS_PROXY") or os.environ.get("https_proxy")
    url = urllib.parse.urlsplit(proxy or constants.ENDPOINT)
    return url.hostname or "huggingface.co", url.port or (443 if url.scheme == "https" else 80)


def _reachable(host: tuple[str, int]) -> bool:
    try:
        with socket.create_connection(host, timeout=_HUB_PROBE_TIMEOUT_S):
            return True
    except OSError:
        return False
