"""The feature cache: every scene's visual and text tokens, encoded once by a frozen backbone.

Training only ever sees these cached tokens, which is what makes 200K adapter steps cheap. A
feature file is one safetensors file of padded arrays:

    visual       float32 (num_scenes, max_objects + 1, D)  crops in box order, then the workspace
    visual_mask  bool    (num_scenes, max_objects + 1)     True for the N + 1 real tokens
    text         float32 (num_scenes, max_tuples, D)        one token per <reference, relation> tuple
    text_mask    bool    (num_scenes, max_tuples)
    targets      int32   (num_scenes, max_tuples)           ground-truth visual token (N = the table)

plus metadata: the cache key (backbone fingerprint + dataset hash + featurize config), scene ids,
reference phrases, prompt and the backbone's logit scale. Note that the table is token N, so its
position varies with the number of boxes; the mask, not the position, tells tokens apart.
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import json
import logging
import shutil
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Protocol

import numpy as np

from ocplace import serial
from ocplace.errors import FeaturesError
from ocplace.models.backbone import Backbone, PromptConfig
from ocplace.paths import atomic_path, file_lock, remove_tree

log = logging.getLogger(__name__)

FORMAT_VERSION = "1"
ARRAY_NAMES = ("visual", "visual_mask", "text", "text_mask", "targets")


@dataclasses.dataclass(frozen=True)
class SceneToFeaturize:
    """One scene before encoding: crops, workspace image, phrases, targets (the dataset's contract with this module).

    Any object with these attributes will do, e.g. the dataset loader's own record type.
    """

    scene_id: str
    crops: np.ndarray  # uint8 (N, S, S, 3) square object crops, N <= max_objects, in box order
    workspace: np.ndarray  # uint8 (H, W, 3) the whole top-down image: visual token N, the table
    texts: tuple[str, ...]  # one reference phrase per tuple, e.g. "red bowl" or "table"
    targets: np.ndarray  # int32 (L,) ground-truth token per tuple among the N + 1 visual tokens


class SceneLike(Protocol):
    """What `featurize` reads of a scene: `SceneToFeaturize`'s attributes, on any object (the dataset loader's
    `SceneExample`, a baseline's own)."""

    @property
    def scene_id(self) -> str: ...
    @property
    def crops(self) -> np.ndarray: ...
    @property
    def workspace(self) -> np.ndarray: ...
    @property
    def texts(self) -> tuple[str, ...]: ...
    @property
    def targets(self) -> np.ndarray: ...


def check_example(example, max_objects: int, max_tuples: int) -> None:
    """Raises FeaturesError naming the scene if `example` breaks the SceneToFeaturize contract."""
    crops, workspace, targets = (np.asarray(x) for x in (example.crops, example.workspace, example.targets))
    problems = []
    if crops.dtype != np.uint8 or crops.ndim != 4 or crops.shape[-1] != 3:
        problems.append(f"crops must be uint8 (N, S, S, 3), got {crops.dtype} {crops.shape}")
    elif len(crops) > max_objects:
        problems.append(f"{len(crops)} crops, more than max_objects = {max_objects}")
    if workspace.dtype != np.uint8 or workspace.ndim != 3 or workspace.shape[-1] != 3:
        problems.append(f"workspace must be uint8 (H, W, 3), got {workspace.dtype} {workspace.shape}")
    if not 1 <= len(example.texts) <= max_tuples or targets.shape != (len(example.texts),):
        problems.append(
            f"need 1..{max_tuples} texts and one target each, got {len(example.texts)} texts "
            f"and targets of shape {targets.shape}"
        )
    elif targets.min() < 0 or targets.max() > len(crops):
        problems.append(f"targets {targets.tolist()} outside 0..{len(crops)} (N = {len(crops)} is the table)")
    if problems:
        raise FeaturesError(f"scene {example.scene_id}: " + "; ".join(problems))


@dataclasses.dataclass(frozen=True)
class FeaturizeConfig:
    max_objects: int = 5  # a scene holds 5 objects, so at most 5 boxes
    max_tuples: int = 2  # the 2obj level has two tuples
    chunk_scenes: int = 64  # scenes per resumable chunk
    prompt: PromptConfig = PromptConfig()

    @property
    def max_tokens(self) -> int:
        return self.max_objects + 1

    def content_json(self) -> str:
        """The settings that change the file's content (not `chunk_scenes`)."""
        return json.dumps({k: v for k, v in dataclasses.asdict(self).items() if k != "chunk_scenes"}, sort_keys=True)


@dataclasses.dataclass(frozen=True)
class FeatureInfo:
    """A feature file's metadata."""

    key: str  # features_key(backbone_fingerprint, dataset_hash, config)
    backbone_fingerprint: str
    dataset_hash: str
    config: FeaturizeConfig
    logit_scale: float
    dim: int

    def to_metadata(self) -> dict[str, str]:
        return {
            "format_version": FORMAT_VERSION,
            "key": self.key,
            "backbone_fingerprint": self.backbone_fingerprint,
            "dataset_hash": self.dataset_hash,
            "config": serial.to_json(self.config),
            "logit_scale": repr(self.logit_scale),
            "dim": str(self.dim),
        }

    @classmethod
    def from_metadata(cls, meta: dict[str, str]) -> FeatureInfo:
        fields = json.loads(meta["config"])
        config = serial.from_dict(FeaturizeConfig, fields)
        return cls(
            meta["key"],
            meta["backbone_fingerprint"],
            meta["dataset_hash"],
            config,
            float(meta["logit_scale"]),
            int(meta["dim"]),
        )


@dataclasses.dataclass(frozen=True)
class Features:
    """A loaded feature file; shapes as in the module docstring."""

    visual: np.ndarray
    visual_mask: np.ndarray
    text: np.ndarray
    text_mask: np.ndarray
    targets: np.ndarray
    scene_ids: tuple[str, ...]
    phrases: tuple[tuple[str, ...], ...]  # the reference phrases of each scene, before prompting
    info: FeatureInfo

    @property
    def num_scenes(self) -> int:
        return len(self.scene_ids)

    @property
    def dim(self) -> int:
        return self.visual.shape[-1]

    def arrays(self) -> tuple[np.ndarray, ...]:
        return tuple(getattr(self, name) for name in ARRAY_NAMES)

    def subset(self, indices) -> Features:
        indices = np.asarray(indices, dtype=np.int64)
        picked = {name: getattr(self, name)[indices] for name in ARRAY_NAMES}
        return dataclasses.replace(
            self,
            **picked,
            scene_ids=tuple(self.scene_ids[i] for i in indices),
            phrases=tuple(self.phrases[i] for i in indices),
        )


def without_objects(features: Features, dataset_dir: str | Path, split: str, held_out: Iterable[str]) -> Features:
    """`features` without the `held_out` objects (library names) as crops or references: their crop tokens leave
    the visual tokens, the tuples that refer to them leave the text, and a scene left without a tuple is
    dropped. For selection runs (the seen colour variants held out of the adapters' training,
    docs/settings.md); the result's key says what was held out. Not everything of them goes: the workspace
    token (the whole image, the table's) may still show them, as may a scene whose held object is one."""
    from ocplace.sim.dataset.job import listed_scenes

    held_out = sorted(set(held_out))
    infos = {scene.name: scene.info() for scene in listed_scenes(dataset_dir, split)}
    held: np.ndarray = np.zeros(features.visual_mask.shape, bool)  # (num_scenes, max_tokens)
    for row, scene_id in enumerate(features.scene_ids):
        info = infos[scene_id]
        names = {obj.object_id: obj.name for obj in info.objects}
        for token, object_id in enumerate(info.boxes.object_ids):
            held[row, token] = names[int(object_id)] in held_out
    referred = np.take_along_axis(held, np.clip(features.targets, 0, held.shape[-1] - 1), axis=1)
    text_mask = features.text_mask & ~referred
    payload = json.dumps([features.info.key, "without", held_out])
    masked = dataclasses.replace(
        features,
        visual_mask=features.visual_mask & ~held,
        text_mask=text_mask,
        info=dataclasses.replace(features.info, key=hashlib.sha256(payload.encode()).hexdigest()),
    )
    return masked.subset(np.flatnonzero(text_mask.any(axis=1)))


def features_key(backbone_fingerprint: str, dataset_hash: str, config: FeaturizeConfig) -> str:
    payload = json.dumps([FORMAT_VERSION, backbone_fingerprint, dataset_hash, config.content_json()])
    return hashlib.sha256(payload.encode()).hexdigest()


def featurize(
    examples: Iterable[SceneLike],
    backbone: Backbone,
    out_path,
    *,
    dataset_hash: str,
    config: FeaturizeConfig = FeaturizeConfig(),
    total: int | None = None,
    progress: bool = True,
) -> Path:
    """Encodes every example once into `out_path`; returns it.

    A file already holding the same key (same backbone, data and config) is left alone without
    reading `examples`. Work is done in chunks of `config.chunk_scenes` scenes, each written
    atomically next to the output, so an interrupted run resumes where it stopped.
    """
    from ocplace.runtime.progress import progress_bar

    out_path = Path(out_path)
    info = FeatureInfo(
        features_key(backbone.fingerprint, dataset_hash, config),
        backbone.fingerprint,
        dataset_hash,
        config,
        float(backbone.logit_scale),
        int(backbone.dim),
    )
    with file_lock(out_path):  # concurrent trainings share this file: one encodes, the others wait for it
        if _holds_key(out_path, info.key):
            log.info("features up to date: %s", out_path)
            return out_path
        parts = _parts_dir(out_path, info.key, config.chunk_scenes)
        _remove_stale_parts(out_path, keep=parts)
        parts.mkdir(parents=True, exist_ok=True)
        iterator = iter(examples)
        with progress_bar(total=total, unit="scene", desc="featurize", enabled=progress) as bar:
            for index in itertools.count():
                chunk = list(itertools.islice(iterator, config.chunk_scenes))
                if not chunk:
                    break
                path = parts / f"chunk_{index:06d}.safetensors"
                if not path.exists():
                    _write(path, encode_chunk(chunk, backbone, config), info, _scene_meta(chunk))
                bar.update(len(chunk))
        _write(out_path, *_merge(sorted(parts.glob("chunk_*.safetensors")), info))
        shutil.rmtree(parts)
    return out_path


def featurize_split(
    dataset_dir, split: str, backbone: Backbone, out=None, config: FeaturizeConfig = FeaturizeConfig(), progress=True
) -> Path:
    """A dataset split's feature file: at `out`, or at the cache path every method reads (one per backbone
    and dataset); a cached no-op once made."""
    from ocplace.sim.dataset.identity import dataset_hash, split_features_path
    from ocplace.sim.dataset.job import scene_dirs
    from ocplace.sim.dataset.loader import iter_examples

    return featurize(
        iter_examples(dataset_dir, split),
        backbone,
        out or split_features_path(dataset_dir, split, backbone.fingerprint),
        dataset_hash=dataset_hash(dataset_dir, split),
        config=config,
        total=len(scene_dirs(dataset_dir, split)),
        progress=progress,
    )


def featurize_split_task(dataset_dir, split: str, backbone_spec: str, out, config: FeaturizeConfig) -> Path:
    """`featurize_split` as an executor task: loads the backbone in the worker."""
    from ocplace.models.backbone import load_backbone

    return featurize_split(dataset_dir, split, load_backbone(backbone_spec), out, config, progress=True)


def encode_chunk(chunk: Sequence[SceneLike], backbone: Backbone, config: FeaturizeConfig) -> dict[str, np.ndarray]:
    """Padded arrays (see the module docstring) for a list of scenes."""
    for example in chunk:
        check_example(example, config.max_objects, config.max_tuples)
    images = [crop for example in chunk for crop in example.crops] + [example.workspace for example in chunk]
    image_features = encode_images_any_size(backbone, images)
    phrases = [phrase for example in chunk for phrase in example.texts]
    text_features = backbone.encode_texts([config.prompt.text_for(phrase) for phrase in phrases])

    count, dim = len(chunk), backbone.dim
    arrays = {
        "visual": np.zeros((count, config.max_tokens, dim), np.float32),
        "visual_mask": np.zeros((count, config.max_tokens), bool),
        "text": np.zeros((count, config.max_tuples, dim), np.float32),
        "text_mask": np.zeros((count, config.max_tuples), bool),
        "targets": np.zeros((count, config.max_tuples), np.int32),
    }
    crop_row, text_row, workspace_row = 0, 0, len(images) - count
    for i, example in enumerate(chunk):
        n, num_texts = len(example.crops), len(example.texts)
        arrays["visual"][i, :n] = image_features[crop_row : crop_row + n]
        arrays["visual"][i, n] = image_features[workspace_row + i]
        arrays["visual_mask"][i, : n + 1] = True
        arrays["text"][i, :num_texts] = text_features[text_row : text_row + num_texts]
        arrays["text_mask"][i, :num_texts] = True
        arrays["targets"][i, :num_texts] = example.targets
        crop_row, text_row = crop_row + n, text_row + num_texts
    return arrays


def encode_images_any_size(backbone: Backbone, images: list[np.ndarray]) -> np.ndarray:
    """`(len(images), D)` features; images of equal shape are encoded together."""
    features = np.zeros((len(images), backbone.dim), np.float32)
    by_shape: dict[tuple[int, ...], list[int]] = {}
    for index, image in enumerate(images):
        by_shape.setdefault(image.shape, []).append(index)
    for indices in by_shape.values():
        features[indices] = backbone.encode_images(np.stack([images[i] for i in indices]))
    return features


def read_info(path) -> FeatureInfo:
    """The metadata of a feature file, without loading its arrays."""
    return _read_metadata(path)[0]


def load_features(path, expected_fingerprint: str | None = None) -> Features:
    """A feature file; with `expected_fingerprint`, refuses features of another backbone."""
    from safetensors.numpy import load_file

    info, meta = _read_metadata(path)
    if expected_fingerprint is not None and info.backbone_fingerprint != expected_fingerprint:
        raise FeaturesError(
            f"{path} was encoded by another backbone (fingerprint "
            f"{info.backbone_fingerprint[:12]}, expected {expected_fingerprint[:12]}); "
            "run `ocplace featurize` again with this backbone"
        )
    arrays = load_file(str(path))
    scenes = json.loads(meta["scenes"])
    return Features(
        **{name: arrays[name] for name in ARRAY_NAMES},
        scene_ids=tuple(s["id"] for s in scenes),
        phrases=tuple(tuple(s["texts"]) for s in scenes),
        info=info,
    )


def _read_metadata(path) -> tuple[FeatureInfo, dict[str, str]]:
    from safetensors import SafetensorError, safe_open

    try:
        with safe_open(str(path), framework="numpy") as handle:
            meta = handle.metadata() or {}
        return FeatureInfo.from_metadata(meta), meta
    except FileNotFoundError as error:
        raise FeaturesError(f"no feature file at {path}; create it with `ocplace featurize`") from error
    except (SafetensorError, OSError, KeyError, ValueError, TypeError) as error:
        raise FeaturesError(
            f"{path} is not a readable ocplace feature file ({error}); delete it and run `ocplace featurize` again"
        ) from error


def save_features(features: Features, path) -> Path:
    """Writes `features` (e.g. a subset, or synthetic ones) as a feature file."""
    scenes = [
        {"id": scene_id, "texts": list(phrases)} for scene_id, phrases in zip(features.scene_ids, features.phrases)
    ]
    _write(Path(path), dict(zip(ARRAY_NAMES, features.arrays())), features.info, scenes)
    return Path(path)


def _scene_meta(chunk: Sequence[SceneLike]) -> list[dict]:
    return [{"id": example.scene_id, "texts": list(example.texts)} for example in chunk]


def _write(path: Path, arrays: dict[str, np.ndarray], info: FeatureInfo, scenes: list[dict]) -> None:
    from safetensors.numpy import save_file

    metadata = {**info.to_metadata(), "scenes": json.dumps(scenes)}
    with atomic_path(path) as tmp:
        save_file(arrays, str(tmp), metadata=metadata)


def _merge(chunk_paths: list[Path], info: FeatureInfo) -> tuple[dict[str, np.ndarray], FeatureInfo, list[dict]]:
    from safetensors import safe_open
    from safetensors.numpy import load_file

    if not chunk_paths:
        raise FeaturesError("no scenes to featurize: the dataset yielded no examples")
    arrays: dict[str, list[np.ndarray]] = {name: [] for name in ARRAY_NAMES}
    scenes: list[dict] = []
    for path in chunk_paths:
        with safe_open(str(path), framework="numpy") as handle:
            scenes += json.loads(handle.metadata()["scenes"])
        for name, array in load_file(str(path)).items():
            arrays[name].append(array)
    return {name: np.concatenate(parts) for name, parts in arrays.items()}, info, scenes


def _holds_key(path: Path, key: str) -> bool:
    if not path.exists():
        return False
    try:
        return read_info(path).key == key
    except FeaturesError as error:
        log.warning("rebuilding %s: %s", path, error)
        return False


def _parts_dir(out_path: Path, key: str, chunk_scenes: int) -> Path:
    return out_path.with_name(f".{out_path.name}.parts-{key[:16]}-{chunk_scenes}")


def _remove_stale_parts(out_path: Path, keep: Path) -> None:
    """Chunks of an interrupted run for another backbone, data or config are useless now."""
    for stale in out_path.parent.glob(f".{out_path.name}.parts-*"):
        if stale != keep:
            remove_tree(stale)
