"""What both baselines read from a scene: its camera, the scene objects' boxes, the held footprint.

Only what a robot would have (eval/api.py): the record's camera, its boxes with the table-frame
AABBs of the objects that have a box, and the held object's footprint.
"""

from __future__ import annotations

import math

import numpy as np

from ocplace.errors import InvalidPlacementProblem
from ocplace.sim import metric
from ocplace.sim.camera import Camera
from ocplace.sim.dataset.records import SceneInfo
from ocplace.sim.metric import GroundedTuple, PlacementProblem
from ocplace.sim.vectors import vec3


def top_down_camera(scene: SceneInfo) -> Camera:
    """The scene's camera; only a straight-down camera (any height, FOV) is modelled, as in the benchmark."""
    pinhole = scene.camera
    fx, fy = pinhole.intrinsics[0, 0], pinhole.intrinsics[1, 1]
    camera = Camera(
        width=pinhole.width,
        height=pinhole.height,
        fov_x_deg=math.degrees(2.0 * math.atan(pinhole.width / 2.0 / fx)),
        position=vec3(pinhole.position),
    )
    if not np.allclose(pinhole.rotation, camera.rotation, atol=1e-6) or not math.isclose(fy, fx):
        raise InvalidPlacementProblem(
            "the baselines need a camera looking straight down with square pixels "
            f"(scene {scene.id}); re-render the scene with the default camera"
        )
    return camera


def visible_aabbs(scene: SceneInfo) -> np.ndarray:
    """`(N, 2, 2)` table-plane AABBs of the objects that have a box, in box order."""
    by_id = {obj.object_id: obj.aabb for obj in scene.objects}
    aabbs = [by_id[int(object_id)][:, :2] for object_id in scene.boxes.object_ids]
    return np.stack(aabbs) if aabbs else np.zeros((0, 2, 2))


def collision_problem(scene: SceneInfo) -> PlacementProblem:
    """A placement problem without relations: the footprint inside the table and clear of every box."""
    problem = metric.encode_problem(
        [GroundedTuple("middle")], visible_aabbs(scene), scene.held_object.footprint_half_extents
    )
    return problem._replace(tuple_mask=np.zeros_like(problem.tuple_mask))  # padded tuples always hold


def free_grid(scene: SceneInfo, grid: metric.Grid = metric.DEFAULT_GRID) -> np.ndarray:
    """`(nx, ny)` bool: cells of the metric's grid where the held object fits (table and boxes only)."""
    return metric.feasible_grid(collision_problem(scene), grid)
