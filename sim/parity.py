"""MuJoCo vs PyBullet parity on the same scene specs (issue: foundation, "PyBullet parity").

(a) physics off, objects at MuJoCo's settled poses: object origins projected by each engine's own
    camera matrices agree within 1 px, and segmentation boxes agree (IoU) for well-visible objects
    (the mean offset between the two engines' object masks is reported too);
(b) depth on table pixels agrees within 2 mm;
(c) after the same drop, both engines settle every object on the table (the physics may differ).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ocplace.runtime.progress import progress_bar
from ocplace.sim.boxes import boxes_from_segmentation
from ocplace.sim.mujoco_backend import MujocoScenes, object_hull_points
from ocplace.sim.pybullet_backend import PybulletScenes
from ocplace.sim.scene import SceneSpec, sample_scene_spec, split_pools


@dataclasses.dataclass(frozen=True)
class ParityConfig:
    scenes: int = 50
    seed: int = 0
    split: str = "seen"
    renderer: str = "tiny"
    iou_min_pixels: int = 500  # boxes are compared for objects at least this visible
    centre_tolerance_px: float = 1.0
    iou_threshold: float = 0.9
    depth_tolerance_m: float = 0.002
    sink_tolerance_m: float = 0.005


def default_config() -> ParityConfig:
    return ParityConfig()


def smoke_config() -> ParityConfig:
    return ParityConfig(scenes=3)


def mujoco_projection(arena: MujocoScenes, points: np.ndarray) -> np.ndarray:
    """`(N, 3)` world points -> `(N, 2)` pixels through the compiled MuJoCo camera."""
    model, data = arena.model, arena.data
    camera = model.camera("top").id
    width, height = arena.config.camera.width, arena.config.camera.height
    rotation = data.cam_xmat[camera].reshape(3, 3)
    local = (points - data.cam_xpos[camera]) @ rotation  # MuJoCo camera: x right, y up, looks along -z
    focal = (height / 2.0) / np.tan(np.radians(model.cam_fovy[camera]) / 2.0)
    u = width / 2.0 + focal * local[:, 0] / -local[:, 2] - 0.5
    v = height / 2.0 - focal * local[:, 1] / -local[:, 2] - 0.5
    return np.stack([u, v], axis=-1)


def pybullet_projection(scenes: PybulletScenes, points: np.ndarray) -> np.ndarray:
    """`(N, 3)` world points -> `(N, 2)` pixels through PyBullet's view and projection matrices."""
    view = np.asarray(scenes._view).reshape(4, 4, order="F")
    projection = np.asarray(scenes._projection).reshape(4, 4, order="F")
    homogeneous = np.concatenate([points, np.ones((len(points), 1))], axis=1)
    clip = homogeneous @ (projection @ view).T
    ndc = clip[:, :3] / clip[:, 3:4]
    width, height = scenes.config.camera.width, scenes.config.camera.height
    return np.stack([(ndc[:, 0] + 1) / 2 * width - 0.5, (1 - ndc[:, 1]) / 2 * height - 0.5], axis=-1)


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    overlap = np.maximum(0, np.minimum(a[2:], b[2:]) - np.maximum(a[:2], b[:2])).prod()
    union = (a[2:] - a[:2]).prod() + (b[2:] - b[:2]).prod() - overlap
    return float(overlap / union)


def compare_static(mj: MujocoScenes, pb: PybulletScenes, spec: SceneSpec, config: ParityConfig) -> dict:
    """Renders the MuJoCo-settled scene in both engines with physics off."""
    scene = mj.build(spec)
    names = scene.spec.objects
    positions, quaternions = mj.poses(names)
    pb.activate(names, scene.spec.table_texture)
    pb.set_poses(names, positions, quaternions)
    _, pb_depth, pb_segmentation = pb.render(names)

    centre_error = np.abs(mujoco_projection(mj, positions) - pybullet_projection(pb, positions)).max()
    centroid_offsets = []
    for object_id in range(1, len(names) + 1):
        mj_pixels, pb_pixels = np.argwhere(scene.segmentation == object_id), np.argwhere(pb_segmentation == object_id)
        if len(mj_pixels) >= config.iou_min_pixels and len(pb_pixels):
            centroid_offsets.append(pb_pixels.mean(axis=0) - mj_pixels.mean(axis=0))
    mj_boxes = boxes_from_segmentation(scene.segmentation, config.iou_min_pixels)
    pb_boxes = boxes_from_segmentation(pb_segmentation, 1)
    ious = []
    for object_id, box in zip(mj_boxes.object_ids, mj_boxes.boxes, strict=True):
        other = pb_boxes.box_of(object_id)
        ious.append(0.0 if other is None else _iou(box.astype(float), other.astype(float)))
    table = (scene.segmentation == 0) & (pb_segmentation == 0) & (scene.depth < 1.0) & (pb_depth < 1.0)
    depth_error = float(np.abs(scene.depth[table] - pb_depth[table]).max()) if table.any() else np.nan
    return {
        "seed": scene.spec.seed,
        "centre_error_px": float(centre_error),
        "mask_centroid_offsets_px": np.asarray(centroid_offsets).tolist(),
        "min_iou": float(min(ious)) if ious else np.nan,
        "boxes_compared": len(ious),
        "table_depth_error_m": depth_error,
        "table_pixels": int(table.sum()),
    }


def _on_table(aabbs: np.ndarray, half_extents: tuple[float, float], sink: float) -> bool:
    centres = aabbs[:, :, :2].mean(axis=1)
    inside = np.all(np.abs(centres) <= np.asarray(half_extents), axis=1)
    return bool(np.all(inside) and np.all(aabbs[:, 0, 2] >= -sink))


def compare_drop(mj: MujocoScenes, pb: PybulletScenes, spec: SceneSpec, hulls: dict, config: ParityConfig) -> dict:
    """Drops the same objects from the same poses in both engines."""
    half = mj.config.table.half_extents
    scene = mj.build(spec)
    pb_objects = pb.drop(scene.spec, hulls)
    mj_aabbs = np.array([obj.aabb for obj in scene.objects])
    pb_aabbs = np.array([obj.aabb for obj in pb_objects])
    return {
        "mujoco_on_table": _on_table(mj_aabbs, half, config.sink_tolerance_m),
        "pybullet_on_table": _on_table(pb_aabbs, half, config.sink_tolerance_m),
        "mujoco_lowest_m": float(mj_aabbs[:, 0, 2].min()),
        "pybullet_lowest_m": float(pb_aabbs[:, 0, 2].min()),
    }


def run_parity(library, config: ParityConfig | None = None, progress: bool = True) -> dict:
    """Runs (a), (b) and (c) on `config.scenes` sampled specs; returns per-scene rows and a summary."""
    config = config or default_config()
    objects, textures = split_pools(library, config.split)
    rng = np.random.default_rng(config.seed)
    specs = [sample_scene_spec(rng, objects, textures) for _ in range(config.scenes)]
    used = sorted({name for spec in specs for name in spec.objects})
    hulls = {name: object_hull_points(library.get(name)) for name in used}
    static_rows, drop_rows = [], []
    with (
        MujocoScenes.from_library(library, used) as mj,
        PybulletScenes(
            [library.get(n) for n in used], {n: t.path for n, t in library.textures.items()}, mj.config, config.renderer
        ) as pb,
    ):
        for spec in progress_bar(specs, desc="parity", enabled=progress):
            static_rows.append(compare_static(mj, pb, spec, config))
            drop_rows.append(compare_drop(mj, pb, spec, hulls, config))
    return {
        "config": dataclasses.asdict(config),
        "static": static_rows,
        "drop": drop_rows,
        "summary": summarise(static_rows, drop_rows, config),
    }


def summarise(static_rows: list[dict], drop_rows: list[dict], config: ParityConfig) -> dict:
    centre = max(row["centre_error_px"] for row in static_rows)
    ious = [row["min_iou"] for row in static_rows if row["boxes_compared"]]
    depth = max(row["table_depth_error_m"] for row in static_rows)
    offsets = np.array([o for row in static_rows for o in row["mask_centroid_offsets_px"]]).reshape(-1, 2)
    return {
        "mean_mask_centroid_offset_px": offsets.mean(axis=0).tolist() if len(offsets) else [np.nan, np.nan],
        "max_centre_error_px": centre,
        "min_box_iou": min(ious) if ious else float("nan"),
        "max_table_depth_error_m": depth,
        "mujoco_settled_on_table": sum(row["mujoco_on_table"] for row in drop_rows),
        "pybullet_settled_on_table": sum(row["pybullet_on_table"] for row in drop_rows),
        "scenes": len(static_rows),
        "passed": bool(
            centre <= config.centre_tolerance_px
            and (not ious or min(ious) >= config.iou_threshold)
            and depth <= config.depth_tolerance_m
            and all(row["mujoco_on_table"] and row["pybullet_on_table"] for row in drop_rows)
        ),
    }
