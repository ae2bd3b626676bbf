"""What both baselines read from a scene: its camera, the scene objects' boxes, the held footprint.

Only what a robot would have (eval/api.py): `meta["camera"]`, `meta["boxes"]` with the
table-frame AABBs of the objects that have a box, and the held object's footprint.
"""

from __future__ import annotations

import math

import numpy as np

from ocplace.errors import InvalidPlacementProblem
from ocplace.sim import metric
from ocplace.sim.camera import Camera
from ocplace.sim.metric import GroundedTuple, PlacementProblem


def camera_from_meta(meta: dict) -> Camera:
    """The scene's camera; only a straight-down camera (any height, FOV) is modelled, as in the benchmark."""
    info = meta["camera"]
    pose = np.asarray(info["world_from_camera"], dtype=np.float64)
    camera = Camera(
        width=int(info["width"]),
        height=int(info["height"]),
        fov_x_deg=math.degrees(2.0 * math.atan(info["width"] / 2.0 / info["fx"])),
        position=tuple(float(v) for v in pose[:3, 3]),
    )
    if not np.allclose(pose[:3, :3], camera.rotation, atol=1e-6) or not math.isclose(info["fy"], info["fx"]):
        raise InvalidPlacementProblem(
            "the baselines need a camera looking straight down with square pixels "
            f"(scene {meta.get('id')}); re-render the scene with the default camera"
        )
    return camera


def visible_aabbs(meta: dict) -> np.ndarray:
    """`(N, 2, 2)` table-plane AABBs of the objects that have a box, in box order."""
    by_id = {obj["object_id"]: obj["aabb"] for obj in meta["objects"]}
    aabbs = [np.asarray(by_id[box["object_id"]], dtype=np.float64)[:, :2] for box in meta["boxes"]]
    return np.stack(aabbs) if aabbs else np.zeros((0, 2, 2))


def held_half_extents(meta: dict) -> np.ndarray:
    return np.asarray(meta["held_object"]["footprint_half_extents"], dtype=np.float64)


def collision_problem(meta: dict) -> PlacementProblem:
    """A placement problem without relations: the footprint inside the table and clear of every box."""
    problem = metric.encode_problem([GroundedTuple("middle")], visible_aabbs(meta), held_half_extents(meta))
    return problem._replace(tuple_mask=np.zeros_like(problem.tuple_mask))  # padded tuples always hold


def free_grid(meta: dict, grid: metric.Grid = metric.DEFAULT_GRID) -> np.ndarray:
    """`(nx, ny)` bool: cells of the metric's grid where the held object fits (table and boxes only)."""
    return metric.feasible_grid(collision_problem(meta), grid)
