"""A simple object detector from depth: table-plane removal and connected components.

For RGB-D input without masks. Every pixel is back-projected with the camera; pixels standing
more than `min_height` above the table plane (world z = 0, refined by a least-squares fit to the
pixels near it, so a camera pose a few millimetres off does not matter) are objects. Depth
edges (neighbours more than `edge_jump` apart in depth) are cut out so touching objects at
different heights separate; OpenCV's connected components then give one box per component of at
least `min_area` pixels, in the pixel-edge convention of `sim.boxes` (u0, v0, u1, v1).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable

import cv2
import numpy as np

from ocplace.errors import PolicyInputError
from ocplace.serial import bounded
from ocplace.sim.pinhole import PinholeCamera
from ocplace.vocabulary import TEST_SUBSETS


@dataclasses.dataclass(frozen=True)
class DetectorConfig:
    min_height: float = bounded(0.005, 0.0, 1.0)  # metres above the table plane
    plane_band: float = bounded(0.02, 0.0, 1.0)  # metres: pixels this close to z = 0 refine the plane fit
    edge_jump: float = bounded(0.003, 1e-5, 1.0)  # metres of depth between neighbours that cut two components apart
    min_area: int = bounded(200, 1, 1_000_000)  # pixels; the dataset boxes objects with >= 200 visible pixels
    max_range: float = bounded(10.0, 0.1, 1000.0)  # metres; larger or non-positive depth is invalid (no return)
    aabb_margin: float = bounded(0.005, 0.0, 0.5)  # metres added on every side of a footprint estimated from depth


def default_config() -> DetectorConfig:
    return DetectorConfig()


def heights_above_table(
    depth: np.ndarray, camera: PinholeCamera, config: DetectorConfig = DetectorConfig()
) -> np.ndarray:
    """`(H, W)` metres above the (refined) table plane; NaN where depth is invalid."""
    depth = np.asarray(depth, np.float64)
    v, u = np.mgrid[: depth.shape[0], : depth.shape[1]]
    valid = (depth > 0) & (depth < config.max_range) & np.isfinite(depth)
    points = camera.pixel_to_world(np.stack([u, v], axis=-1), np.where(valid, depth, 0.0))
    height = np.where(valid, points[..., 2], np.nan)
    near = valid & (np.abs(height) < config.plane_band)
    if near.sum() >= 3:
        x, y, z = points[near][:, 0], points[near][:, 1], points[near][:, 2]
        coefficients, *_ = np.linalg.lstsq(np.stack([x, y, np.ones_like(x)], axis=1), z, rcond=None)
        height = height - (coefficients[0] * points[..., 0] + coefficients[1] * points[..., 1] + coefficients[2])
    return height


def object_mask(depth: np.ndarray, camera: PinholeCamera, config: DetectorConfig = DetectorConfig()) -> np.ndarray:
    """`(H, W)` bool: pixels above the table, minus depth edges."""
    height = heights_above_table(depth, camera, config)
    mask = np.nan_to_num(height, nan=-1.0) > config.min_height
    depth = np.asarray(depth, np.float64)
    edges = np.zeros_like(mask)
    edges[:, 1:] |= np.abs(np.diff(depth, axis=1)) > config.edge_jump
    edges[1:, :] |= np.abs(np.diff(depth, axis=0)) > config.edge_jump
    return mask & ~edges


def detect_boxes(depth: np.ndarray, camera, config: DetectorConfig = DetectorConfig()) -> np.ndarray:
    """int32 `(N, 4)` boxes (u0, v0, u1, v1) of the objects on the table, largest first."""
    camera = PinholeCamera.from_any(camera)
    depth = np.asarray(depth)
    if depth.shape != (camera.height, camera.width):
        raise PolicyInputError(
            f"depth is {depth.shape[1]}x{depth.shape[0]} but the camera is "
            f"{camera.width}x{camera.height}; pass the camera the depth image was taken with"
        )
    mask = object_mask(depth, camera, config).astype(np.uint8)
    _, _, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    stats = stats[1:]  # component 0 is the background
    stats = stats[stats[:, cv2.CC_STAT_AREA] >= config.min_area]
    stats = stats[np.argsort(-stats[:, cv2.CC_STAT_AREA], kind="stable")]
    u0, v0 = stats[:, cv2.CC_STAT_LEFT], stats[:, cv2.CC_STAT_TOP]
    return (
        np.stack([u0, v0, u0 + stats[:, cv2.CC_STAT_WIDTH], v0 + stats[:, cv2.CC_STAT_HEIGHT]], axis=1)
        .astype(np.int32)
        .reshape(-1, 4)
    )


def estimate_aabbs(
    depth: np.ndarray,
    camera,
    boxes: np.ndarray,
    segmentation: np.ndarray | None = None,
    object_ids: np.ndarray | None = None,
    config: DetectorConfig = DetectorConfig(),
) -> np.ndarray:
    """`(N, 2, 2)` table-frame x-y AABBs of the objects in `boxes` `(N, 4)`, from depth.

    An object's pixels are its segmentation mask (with `segmentation` and `object_ids`), else the
    largest connected component of above-table pixels inside its box (neighbours intruding into
    the box are smaller there). They are back-projected; the x-y extent of those points, grown by
    `aabb_margin`, is the footprint. The camera sees only the top of an object, so the estimate
    lies inside the true AABB up to the margin. A box with no pixel above the table (a flat
    object) falls back to where its corners' rays meet the table.
    """
    camera = PinholeCamera.from_any(camera)
    height = np.nan_to_num(heights_above_table(depth, camera, config), nan=-1.0)
    above = height > config.min_height
    aabbs = np.zeros((len(boxes), 2, 2))
    for index, (u0, v0, u1, v1) in enumerate(np.asarray(boxes, np.int64).reshape(-1, 4)):
        inside = above[v0:v1, u0:u1]
        if segmentation is not None and object_ids is not None:
            inside = inside & (segmentation[v0:v1, u0:u1] == object_ids[index])
        else:
            count, labels, stats, _ = cv2.connectedComponentsWithStats(inside.astype(np.uint8), connectivity=8)
            if count > 1:
                inside = labels == 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
        vs, us = np.nonzero(inside)
        if len(vs):
            pixels = np.stack([us + u0, vs + v0], axis=-1)
            xy = camera.pixel_to_world(pixels, np.asarray(depth, np.float64)[vs + v0, us + u0])[:, :2]
        else:
            corners = np.array([[u0, v0], [u1, v0], [u0, v1], [u1, v1]], np.float64) - 0.5
            xy = camera.pixel_to_table(corners)
        aabbs[index] = [xy.min(axis=0) - config.aabb_margin, xy.max(axis=0) + config.aabb_margin]
    return aabbs


def box_iou(boxes_a: np.ndarray, boxes_b: np.ndarray) -> np.ndarray:
    """`(A, B)` intersection over union of pixel-edge boxes `(A, 4)` and `(B, 4)`."""
    a = np.asarray(boxes_a, np.float64).reshape(-1, 1, 4)
    b = np.asarray(boxes_b, np.float64).reshape(1, -1, 4)
    width = np.clip(np.minimum(a[..., 2], b[..., 2]) - np.maximum(a[..., 0], b[..., 0]), 0, None)
    height = np.clip(np.minimum(a[..., 3], b[..., 3]) - np.maximum(a[..., 1], b[..., 1]), 0, None)
    intersection = width * height
    area_a = (a[..., 2] - a[..., 0]) * (a[..., 3] - a[..., 1])
    area_b = (b[..., 2] - b[..., 0]) * (b[..., 3] - b[..., 1])
    return intersection / np.maximum(area_a + area_b - intersection, 1e-12)


@dataclasses.dataclass(frozen=True)
class Recall:
    matched: int  # ground-truth boxes matched by a detection at IoU >= threshold
    total: int  # ground-truth boxes
    detections: int  # boxes the detector returned
    scenes: int
    iou_threshold: float

    @property
    def recall(self) -> float:
        return self.matched / max(self.total, 1)

    @property
    def precision(self) -> float:
        return self.matched / max(self.detections, 1)


def matched_count(detected: np.ndarray, truth: np.ndarray, iou_threshold: float = 0.5) -> int:
    """Ground-truth boxes matched one-to-one (greedy by IoU) by a detection with IoU >= threshold."""
    iou = box_iou(truth, detected)
    matched = 0
    while iou.size and iou.max() >= iou_threshold:
        row, column = np.unravel_index(np.argmax(iou), iou.shape)
        iou[row, :], iou[:, column] = -1.0, -1.0
        matched += 1
    return matched


def box_recall(records: Iterable, config: DetectorConfig = DetectorConfig(), iou_threshold: float = 0.5) -> Recall:
    """Recall of `detect_boxes` against the dataset's boxes (from segmentation) over `SceneRecord`s."""
    matched = total = detections = scenes = 0
    for record in records:
        truth = record.boxes.boxes
        detected = detect_boxes(record.depth, record.camera, config)
        matched += matched_count(detected, truth, iou_threshold)
        total, detections, scenes = total + len(truth), detections + len(detected), scenes + 1
    return Recall(matched, total, detections, scenes, iou_threshold)


def dataset_box_recall(
    dataset_dir,
    splits: Iterable[str] = TEST_SUBSETS,
    config: DetectorConfig = DetectorConfig(),
    iou_threshold: float = 0.5,
) -> dict[str, Recall]:
    """`box_recall` per split of a dataset directory."""
    from ocplace.sim.dataset.job import listed_scenes

    return {
        split: box_recall((scene.read() for scene in listed_scenes(dataset_dir, split)), config, iou_threshold)
        for split in splits
    }
