"""One scene of the dataset on disk: three PNGs and a JSON, readable without this project.

<split>/<scene id>/scene.json          everything but the pixels (schema below)
<split>/<scene id>/rgb.png             uint8 RGB
<split>/<scene id>/depth.png           uint16 planar depth in millimetres
<split>/<scene id>/segmentation.png    uint8 object ids, 0 = table or background
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import cv2
import numpy as np

from ocplace.errors import DatasetError
from ocplace.sim.boxes import Boxes
from ocplace.sim.metric import GroundedTuple, PlacementProblem, encode_problem

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


@dataclasses.dataclass(frozen=True)
class SceneRecord:
    meta: dict  # the scene.json content
    rgb: np.ndarray  # (H, W, 3) uint8
    depth: np.ndarray  # (H, W) float32 metres
    segmentation: np.ndarray  # (H, W) int32

    @property
    def id(self) -> str:
        return self.meta["id"]

    @property
    def tuples(self) -> tuple[TupleRecord, ...]:
        return tuple(TupleRecord(**t) for t in self.meta["tuples"])

    @property
    def boxes(self) -> Boxes:
        entries = self.meta["boxes"]
        return Boxes(
            np.array([b["object_id"] for b in entries], np.int32).reshape(-1),
            np.array([b["box"] for b in entries], np.int32).reshape(-1, 4),
            np.array([b["pixels"] for b in entries], np.int64).reshape(-1),
        )

    def problem(self) -> PlacementProblem:
        return problem_from_meta(self.meta)


def problem_from_meta(meta: dict) -> PlacementProblem:
    """The placement problem of a scene.json, with the ground-truth grounding."""
    aabbs = np.array([obj["aabb"] for obj in meta["objects"]], dtype=np.float64)[:, :, :2]
    tuples = [
        GroundedTuple(t["relation"], None if t["reference_object_id"] == 0 else aabbs[t["reference_object_id"] - 1])
        for t in meta["tuples"]
    ]
    return encode_problem(tuples, aabbs, meta["held_object"]["footprint_half_extents"])


def _encode_png(image: np.ndarray, compression: int) -> bytes:
    ok, encoded = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, compression])
    if not ok:
        raise DatasetError("PNG encoding failed")
    return encoded.tobytes()


def encode_images(
    rgb: np.ndarray, depth: np.ndarray, segmentation: np.ndarray, compression: int = 1
) -> dict[str, bytes]:
    """The three PNG files of a scene, by file name."""
    depth_mm = np.clip(np.round(depth * 1000.0), 0, 65535).astype(np.uint16)
    return {
        "rgb.png": _encode_png(np.ascontiguousarray(rgb[..., ::-1]), compression),
        "depth.png": _encode_png(depth_mm, compression),
        "segmentation.png": _encode_png(segmentation.astype(np.uint8), compression),
    }


def scene_files(meta: dict, images: dict[str, bytes]) -> dict[str, bytes]:
    return {SCENE_FILE: json.dumps(meta, indent=1, sort_keys=True).encode(), **images}


def _read_png(path: Path, flags: int) -> np.ndarray:
    image = cv2.imread(str(path), flags)
    if image is None:
        raise DatasetError(
            f"{path} is missing or not a readable PNG; run `ocplace generate` on the "
            f"dataset again to regenerate that scene"
        )
    return image


def read_meta(scene_dir: Path) -> dict:
    path = Path(scene_dir) / SCENE_FILE
    try:
        meta = json.loads(path.read_text())
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


def read_scene(scene_dir: str | Path) -> SceneRecord:
    scene_dir = Path(scene_dir)
    meta = read_meta(scene_dir)
    rgb = _read_png(scene_dir / "rgb.png", cv2.IMREAD_COLOR)[..., ::-1]
    depth = _read_png(scene_dir / "depth.png", cv2.IMREAD_UNCHANGED).astype(np.float32) / 1000.0
    segmentation = _read_png(scene_dir / "segmentation.png", cv2.IMREAD_UNCHANGED).astype(np.int32)
    return SceneRecord(meta, np.ascontiguousarray(rgb), depth, segmentation)
