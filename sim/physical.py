"""The optional physical check (docs/design.md#success-metric): drop the held object at the placement.

The held object is released upright (yaw 0, matching its footprint) 2 cm above the tallest object
under its footprint, or above the table. The placement is physically successful when the held
object comes to rest within 2 cm of the placement in the table plane and no scene object moved by
more than 1 cm because of it: scene objects are compared with the same scene settled again without
the held object, since a recorded scene can hold an object still rolling slower than the settle
threshold.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ocplace.sim.dataset.records import SceneInfo
from ocplace.sim.mujoco_backend import MujocoScenes


@dataclasses.dataclass(frozen=True)
class PhysicalCheckConfig:
    drop_clearance: float = 0.02  # m above the tallest object under the footprint
    rest_tolerance: float = 0.02  # m, held object's final x-y distance to the placement
    disturbance_tolerance: float = 0.01  # m, largest allowed motion of a scene object


@dataclasses.dataclass(frozen=True)
class PhysicalResult:
    success: bool
    held_offset: float  # m, final x-y distance of the held object to the placement
    max_disturbance: float  # m, largest displacement of a scene object
    release_height: float  # m, height of the held object's base at release


def release_height(placement: np.ndarray, half_extents: np.ndarray, aabbs: np.ndarray, clearance: float) -> float:
    """Base height at release: `clearance` above the tallest AABB under the footprint, or the table."""
    low, high = placement - half_extents, placement + half_extents
    under = np.all((aabbs[:, 0, :2] < high) & (aabbs[:, 1, :2] > low), axis=1)
    return float(max(aabbs[under, 1, 2].max(initial=0.0), 0.0) + clearance)


def physical_check(
    arena: MujocoScenes, scene: SceneInfo, placement: np.ndarray, config: PhysicalCheckConfig = PhysicalCheckConfig()
) -> PhysicalResult:
    """Drops the held object of a dataset scene (a `SceneInfo` or `SceneRecord`) at `placement`."""
    placement = np.asarray(placement, dtype=np.float64)
    names = [obj.name for obj in scene.objects]
    held = scene.held_object.name
    positions = np.stack([obj.position for obj in scene.objects])
    quaternions = np.stack([obj.quaternion for obj in scene.objects])
    aabbs = np.stack([obj.aabb for obj in scene.objects])
    height = release_height(placement, scene.held_object.footprint_half_extents, aabbs, config.drop_clearance)
    arena.activate(names, scene.table_texture)
    arena.set_poses(names, positions, quaternions)
    arena.settle(names)
    undisturbed, _ = arena.poses(names)
    arena.activate([*names, held], scene.table_texture)
    arena.set_poses(names, positions, quaternions)
    arena.set_poses([held], np.array([[placement[0], placement[1], height]]), np.array([[1.0, 0, 0, 0]]))
    arena.settle([*names, held])
    final_positions, _ = arena.poses([*names, held])
    offset = float(np.linalg.norm(final_positions[-1, :2] - placement))
    disturbance = float(np.linalg.norm(final_positions[:-1] - undisturbed, axis=1).max())
    success = offset <= config.rest_tolerance and disturbance <= config.disturbance_tolerance
    return PhysicalResult(success, offset, disturbance, height)
