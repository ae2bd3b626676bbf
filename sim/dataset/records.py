"""One scene of the dataset on disk: three PNGs and a JSON, readable without this project.

<split>/<scene id>/scene.json          everything but the pixels (schema below)
<split>/<scene id>/rgb.png             uint8 RGB
<split>/<scene id>/depth.png           uint16 planar depth in millimetres
<split>/<scene id>/segmentation.png    uint8 object ids, 0 = table or background
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from collections.abc import Mapping
from pathlib import Path

import cv2
import numpy as np

from ocplace.errors import DatasetError
from ocplace.sim.boxes import Boxes
from ocplace.sim.metric import GroundedTuple, PlacementProblem, encode_problem
from ocplace.sim.pinhole import PinholeCamera
from ocplace.sim.scene import SceneSpec

SCHEMA_VERSION = 1
IMAGE_FILES = ("rgb.png", "depth.png", "segmentation.png")
SCENE_FILE = "scene.json"
SCENE_KEYS = (
    "id",
    "split",
    "level",
    "index",
    "instruction",
    "tuples",
    "held_object",
    "table_texture",
    "spec",
    "objects",
    "boxes",
    "camera",
    "oracle",
    "resamples",
    "schema_version",
)


@dataclasses.dataclass(frozen=True)
class TupleRecord:
    reference_object_id: int  # segmentation id of the reference; 0 = the table
    reference_name: str  # the human name used in the instruction, "table" for the table
    relation: str  # canonical relation
    token_index: int  # index of the reference among the N + 1 visual tokens (N = the table)


@dataclasses.dataclass(frozen=True, eq=False)
class ObjectRecord:
    object_id: int  # segmentation id, 1..N: its position in `objects` + 1
    name: str  # library name
    human_name: str  # the name instructions use
    position: np.ndarray  # (3,) float64 world position of the object frame, metres
    quaternion: np.ndarray  # (4,) float64 orientation, w x y z
    aabb: np.ndarray  # (2, 3) float64 world AABB [[xmin, ymin, zmin], [xmax, ymax, zmax]], metres


@dataclasses.dataclass(frozen=True, eq=False)
class HeldObjectRecord:
    name: str  # library name
    human_name: str
    footprint_half_extents: np.ndarray  # (2,) float64 (hx, hy) of its upright x-y footprint, metres


@dataclasses.dataclass(frozen=True, eq=False)
class OracleRecord:
    placement: np.ndarray  # (2,) float64 table-plane x-y, metres: the feasible point deepest inside the region


@dataclasses.dataclass(frozen=True)
class ResampleCounts:
    scenes: int  # scenes drawn again because no relations fitted
    relations: int  # relation draws repeated because the feasible region was empty


@dataclasses.dataclass(frozen=True, eq=False)
class SceneInfo:
    """A scene.json, parsed on construction: the one reader of its fields.

    `dataclasses.replace(record, meta=...)` parses again, so a redacted copy has redacted fields: the
    ground truth (`tuples`, `oracle`) is None where `meta` lacks it.
    """

    meta: dict  # the raw JSON, only for code that writes or hashes it
    id: str = dataclasses.field(init=False, repr=False)  # "<split>-<index, 5 digits>"
    split: str = dataclasses.field(init=False, repr=False)
    index: int = dataclasses.field(init=False, repr=False)  # position in the split
    level: str = dataclasses.field(init=False, repr=False)  # "table", "1obj" or "2obj"
    instruction: str = dataclasses.field(init=False, repr=False)
    instruction_style: str = dataclasses.field(init=False, repr=False)  # the split's templates, "seen" or "unseen"
    tuples: tuple[TupleRecord, ...] | None = dataclasses.field(
        init=False, repr=False
    )  # ground truth, in instruction order
    held_object: HeldObjectRecord = dataclasses.field(init=False, repr=False)
    table_texture: str = dataclasses.field(init=False, repr=False)  # library texture name
    spec: SceneSpec = dataclasses.field(init=False, repr=False)  # rebuilds the scene
    objects: tuple[ObjectRecord, ...] = dataclasses.field(init=False, repr=False)  # in object-id order, visible or not
    boxes: Boxes = dataclasses.field(
        init=False, repr=False
    )  # the visible objects' boxes, ascending id: visual tokens 0..N-1
    camera: PinholeCamera = dataclasses.field(init=False, repr=False)  # what rendered the images
    oracle: OracleRecord | None = dataclasses.field(init=False, repr=False)  # ground truth
    resamples: ResampleCounts = dataclasses.field(init=False, repr=False)

    def __post_init__(self):
        for name, value in _parse(self.meta).items():
            object.__setattr__(self, name, value)

    def true_tuples(self) -> tuple[TupleRecord, ...]:
        """The ground-truth tuples; DatasetError for a redacted record, which holds none."""
        if self.tuples is None:
            raise DatasetError(f"scene {self.id} was redacted: it holds no ground truth")
        return self.tuples

    def true_placement(self) -> np.ndarray:
        """`(2,)` the oracle placement; DatasetError for a redacted record, which holds none."""
        if self.oracle is None:
            raise DatasetError(f"scene {self.id} was redacted: it holds no ground truth")
        return self.oracle.placement

    def problem(self) -> PlacementProblem:
        """The placement problem of the scene, with the ground-truth grounding."""
        aabbs = np.stack([obj.aabb for obj in self.objects])[:, :, :2]
        tuples = [
            GroundedTuple(t.relation, None if t.reference_object_id == 0 else aabbs[t.reference_object_id - 1])
            for t in self.true_tuples()
        ]
        return encode_problem(tuples, aabbs, self.held_object.footprint_half_extents)


@dataclasses.dataclass(frozen=True, eq=False)
class SceneRecord(SceneInfo):
    """A scene.json and its images; built as `SceneRecord(meta, rgb, depth, segmentation)`."""

    rgb: np.ndarray  # (H, W, 3) uint8
    depth: np.ndarray  # (H, W) float32 metres
    segmentation: np.ndarray  # (H, W) int32

    def policy_inputs(self) -> dict:
        """What a robot would hand `PlacementPolicy.place` in this scene, by its argument names: `rgb`, `depth`,
        `boxes_or_segmentation` (`(N, 4)` pixel boxes), `instruction`, `held_footprint`, `camera` and
        `object_aabbs` (`(N, 2, 2)` table-frame x-y AABBs of the boxes' objects). No ground truth."""
        aabb_by_id = {obj.object_id: obj.aabb for obj in self.objects}
        aabbs = np.array([aabb_by_id[int(i)] for i in self.boxes.object_ids], np.float64).reshape(-1, 2, 3)
        return {
            "rgb": self.rgb,
            "depth": self.depth,
            "boxes_or_segmentation": self.boxes.boxes,
            "instruction": self.instruction,
            "held_footprint": self.held_object.footprint_half_extents,
            "camera": self.camera,
            "object_aabbs": aabbs[:, :, :2],
        }


def _parse(meta: dict) -> dict:
    """The typed fields of `SceneInfo`, by name."""
    tuples, held, spec, oracle = meta.get("tuples"), meta["held_object"], meta["spec"], meta.get("oracle")
    return {
        "id": meta["id"],
        "split": meta["split"],
        "index": meta["index"],
        "level": meta["level"],
        "instruction": meta["instruction"],
        "instruction_style": meta["instruction_style"],
        "tuples": None if tuples is None else tuple(TupleRecord(**t) for t in tuples),
        "held_object": HeldObjectRecord(
            held["name"], held["human_name"], np.asarray(held["footprint_half_extents"], np.float64)
        ),
        "table_texture": meta["table_texture"],
        "spec": SceneSpec(tuple(spec["objects"]), spec["table_texture"], spec["held_object"], spec["seed"]),
        "objects": tuple(_object(obj) for obj in meta["objects"]),
        "boxes": _boxes(meta["boxes"]),
        "camera": PinholeCamera.from_json(meta["camera"]),
        "oracle": None if oracle is None else OracleRecord(np.asarray(oracle["placement"], np.float64)),
        "resamples": ResampleCounts(meta["resamples"]["scenes"], meta["resamples"]["relations"]),
    }


def _object(entry: dict) -> ObjectRecord:
    return ObjectRecord(
        entry["object_id"],
        entry["name"],
        entry["human_name"],
        np.asarray(entry["position"], np.float64),
        np.asarray(entry["quaternion"], np.float64),
        np.asarray(entry["aabb"], np.float64),
    )


def _boxes(entries: list[dict]) -> Boxes:
    return Boxes(
        np.array([b["object_id"] for b in entries], np.int32).reshape(-1),
        np.array([b["box"] for b in entries], np.int32).reshape(-1, 4),
        np.array([b["pixels"] for b in entries], np.int64).reshape(-1),
    )


def _encode_png(image: np.ndarray, compression: int) -> bytes:
    ok, encoded = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, compression])
    if not ok:
        raise DatasetError("PNG encoding failed")
    return encoded.tobytes()


def stored_depth(depth: np.ndarray) -> np.ndarray:
    """`(H, W)` uint16: planar depth in metres as a scene stores it, in whole millimetres."""
    return np.clip(np.round(depth * 1000.0), 0, 65535).astype(np.uint16)


def encode_images(
    rgb: np.ndarray, depth: np.ndarray, segmentation: np.ndarray, compression: int = 1
) -> dict[str, bytes]:
    """The three PNG files of a scene, by file name."""
    return {
        "rgb.png": _encode_png(np.ascontiguousarray(rgb[..., ::-1]), compression),
        "depth.png": _encode_png(stored_depth(depth), compression),
        "segmentation.png": _encode_png(segmentation.astype(np.uint8), compression),
    }


def scene_files(meta: dict, images: dict[str, bytes]) -> dict[str, bytes]:
    return {SCENE_FILE: json.dumps(meta, indent=1, sort_keys=True).encode(), **images}


def _read_listed(path: Path, digests: Mapping[str, str] | None) -> bytes:
    """The bytes of a scene file, hashed as they are read when `digests` (file name -> the sha256 the
    dataset's manifest lists) is given; DatasetError when they differ from the listed hash."""
    data = path.read_bytes()
    if digests is not None and hashlib.sha256(data).hexdigest() != digests.get(path.name):
        dataset = path.parent.parent.parent
        raise DatasetError(
            f"{path.name} of scene {path.parent.name} does not match the sha256 that {dataset}/manifest.json "
            "lists: it was edited or damaged after generation, so the scene is not the dataset's. Run "
            f"`ocplace dataset verify --dataset {dataset}` to list every such file, then `ocplace generate --out "
            f"{dataset}` with the dataset's options to regenerate them"
        )
    return data


def _read_png(path: Path, flags: int, digests: Mapping[str, str] | None) -> np.ndarray:
    try:
        data = _read_listed(path, digests)
    except OSError:
        data = b""
    image = cv2.imdecode(np.frombuffer(data, np.uint8), flags) if data else None
    if image is None:
        raise DatasetError(
            f"{path} is missing or not a readable PNG; run `ocplace generate` on the "
            f"dataset again to regenerate that scene"
        )
    return image


def read_meta(scene_dir: Path, digests: Mapping[str, str] | None = None) -> dict:
    """The scene's JSON, checked against `digests` (see `read_scene`) when given."""
    path = Path(scene_dir) / SCENE_FILE
    try:
        meta = json.loads(_read_listed(path, digests))
    except (OSError, ValueError) as error:
        raise DatasetError(
            f"{path} is missing or corrupt ({error}); run `ocplace generate` on the "
            f"dataset again to regenerate that scene"
        ) from None
    if not isinstance(meta, dict):
        raise DatasetError(
            f"{path} is corrupt (not a JSON object); run `ocplace generate` on the dataset again "
            f"to regenerate that scene"
        )
    missing = [key for key in SCENE_KEYS if key not in meta]
    if missing:
        raise DatasetError(f"{path} lacks {missing}; it was not written by this version of ocplace")
    return meta


def _record(meta: dict, rgb_bgr: np.ndarray, depth_mm: np.ndarray, segmentation: np.ndarray) -> SceneRecord:
    """A record from its JSON and its decoded PNGs, whether they were read from disk or made in memory."""
    rgb = np.ascontiguousarray(rgb_bgr[..., ::-1])
    return SceneRecord(meta, rgb, depth_mm.astype(np.float32) / 1000.0, segmentation.astype(np.int32))


def read_scene(scene_dir: str | Path, digests: Mapping[str, str] | None = None) -> SceneRecord:
    """The scene in `scene_dir`. With `digests` (file name -> sha256, from the dataset's manifest) every
    file is hashed as it is read and a DatasetError names the first that differs; readers of a dataset
    pass them (`ocplace.sim.dataset.job.listed_scenes`), so an edited scene is never read as the dataset's."""
    scene_dir = Path(scene_dir)
    meta = read_meta(scene_dir, digests)
    rgb = _read_png(scene_dir / "rgb.png", cv2.IMREAD_COLOR, digests)
    depth = _read_png(scene_dir / "depth.png", cv2.IMREAD_UNCHANGED, digests)
    segmentation = _read_png(scene_dir / "segmentation.png", cv2.IMREAD_UNCHANGED, digests)
    return _record(meta, rgb, depth, segmentation)


def stored_record(meta: dict, rgb: np.ndarray, depth: np.ndarray, segmentation: np.ndarray) -> SceneRecord:
    """The record `read_scene` gives of a scene once written (`scene_files`, `encode_images`), without
    writing it: the JSON round trip, depth in whole millimetres; PNGs are lossless, so nothing else changes."""
    meta = json.loads(json.dumps(meta, sort_keys=True))
    return _record(meta, rgb[..., ::-1], stored_depth(depth), segmentation.astype(np.uint8))
