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
    arena: MujocoScenes, meta: dict, placement: np.ndarray, config: PhysicalCheckConfig = PhysicalCheckConfig()
) -> PhysicalResult:
    """Drops the held object of the scene described by `meta` (a dataset scene.json) at `placement`."""
    placement = np.asarray(placement, dtype=np.float64)
    names = [obj["name"] for obj in meta["objects"]]
    held = meta["held_object"]["name"]
    positions = np.array([obj["position"] for obj in meta["objects"]])
    quaternions = np.array([obj["quaternion"] for obj in meta["objects"]])
    aabbs = np.array([obj["aabb"] for obj in meta["objects"]])
    height = release_height(
        placement, np.asarray(meta["held_object"]["footprint_half_extents"]), aabbs, config.drop_clearance
    )
    arena.activate(names, meta["table_texture"])
    arena.set_poses(names, positions, quaternions)
    arena.settle(names)
    undisturbed, _ = arena.poses(names)
    arena.activate([*names, held], meta["table_texture"])
    arena.set_poses(names, positions, quaternions)
    arena.set_poses([held], np.array([[placement[0], placement[1], height]]), np.array([[1.0, 0, 0, 0]]))
    arena.settle([*names, held])
    final_positions, _ = arena.poses([*names, held])
    offset = float(np.linalg.norm(final_positions[-1, :2] - placement))
    disturbance = float(np.linalg.norm(final_positions[:-1] - undisturbed, axis=1).max())
    success = offset <= config.rest_tolerance and disturbance <= config.disturbance_tolerance
    return PhysicalResult(success, offset, disturbance, height)
