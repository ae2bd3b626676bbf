"""A pinhole camera from intrinsics and a pose: what a robot's RGB-D input comes with.

`sim.camera.Camera` is the simulator's fixed top-down camera; this is the general model the
policy accepts (any intrinsics, any pose), built from the dataset's `meta["camera"]` JSON, a
`sim.camera.Camera`, or arrays. Pixels are (u, v), u right and v down, pixel centres at integers;
depth is planar (along the optical axis), in metres; the camera axes are OpenCV's (x right,
y down, z forward). The table plane is world z = 0.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from ocplace.errors import PolicyInputError


@dataclasses.dataclass(frozen=True, eq=False)
class PinholeCamera:
    intrinsics: np.ndarray  # (3, 3) K
    world_from_camera: np.ndarray  # (4, 4) pose of the camera in the world (table) frame
    width: int
    height: int

    def __post_init__(self):
        intrinsics = np.asarray(self.intrinsics, np.float64)
        pose = np.asarray(self.world_from_camera, np.float64)
        if intrinsics.shape != (3, 3) or pose.shape != (4, 4) or not (np.all(np.isfinite(intrinsics))
                                                                      and np.all(np.isfinite(pose))):
            raise PolicyInputError("a camera needs a finite (3, 3) intrinsics matrix and a (4, 4) world_from_camera "
                                   f"pose, got {intrinsics.shape} and {pose.shape}")
        if not np.allclose(pose[:3, :3] @ pose[:3, :3].T, np.eye(3), atol=1e-6):
            raise PolicyInputError("world_from_camera's rotation block is not orthonormal")
        object.__setattr__(self, "intrinsics", intrinsics)
        object.__setattr__(self, "world_from_camera", pose)

    @classmethod
    def from_any(cls, camera) -> PinholeCamera:
        """A PinholeCamera from itself, a `sim.camera.Camera`, a camera dict or a JSON file path."""
        if isinstance(camera, PinholeCamera):
            return camera
        if isinstance(camera, (str, Path)):
            return cls.from_json(json.loads(Path(camera).read_text()))
        if isinstance(camera, dict):
            return cls.from_json(camera)
        if hasattr(camera, "intrinsics") and hasattr(camera, "world_from_camera"):
            return cls(camera.intrinsics, camera.world_from_camera, int(camera.width), int(camera.height))
        raise PolicyInputError(f"cannot read a camera from {type(camera).__name__}; pass a PinholeCamera, a "
                               "sim.camera.Camera or a dict with intrinsics, world_from_camera, width, height")

    @classmethod
    def from_json(cls, fields: dict) -> PinholeCamera:
        """From the dataset's `meta["camera"]` (`sim.camera.Camera.to_json`) or `to_json`'s output."""
        missing = [k for k in ("intrinsics", "world_from_camera", "width", "height") if k not in fields]
        if missing:
            raise PolicyInputError(f"camera JSON lacks {missing}; it needs intrinsics (3x3), world_from_camera "
                                   "(4x4, metres), width and height (pixels)")
        return cls(np.asarray(fields["intrinsics"]), np.asarray(fields["world_from_camera"]),
                   int(fields["width"]), int(fields["height"]))

    def to_json(self) -> dict:
        return {"intrinsics": self.intrinsics.tolist(), "world_from_camera": self.world_from_camera.tolist(),
                "width": self.width, "height": self.height}

    @property
    def rotation(self) -> np.ndarray:
        return self.world_from_camera[:3, :3]

    @property
    def position(self) -> np.ndarray:
        return self.world_from_camera[:3, 3]

    def world_to_pixel(self, points: np.ndarray) -> np.ndarray:
        """`(..., 3)` world points -> `(..., 2)` pixels (u, v)."""
        camera_points = (np.asarray(points, np.float64) - self.position) @ self.rotation
        projected = camera_points @ self.intrinsics.T
        return projected[..., :2] / projected[..., 2:3]

    def pixel_to_world(self, pixels: np.ndarray, depth: np.ndarray) -> np.ndarray:
        """`(..., 2)` pixels with `(...)` planar depth in metres -> `(..., 3)` world points."""
        rays = self._camera_rays(pixels)
        return (rays * np.asarray(depth, np.float64)[..., None]) @ self.rotation.T + self.position

    def table_to_pixel(self, xy: np.ndarray) -> np.ndarray:
        """`(..., 2)` points on the table plane z = 0 -> `(..., 2)` pixels."""
        xy = np.asarray(xy, np.float64)
        return self.world_to_pixel(np.concatenate([xy, np.zeros_like(xy[..., :1])], axis=-1))

    def pixel_to_table(self, pixels: np.ndarray) -> np.ndarray:
        """`(..., 2)` pixels -> `(..., 2)` x-y where each pixel's ray meets the table plane z = 0."""
        directions = self._camera_rays(pixels) @ self.rotation.T
        with np.errstate(divide="ignore", invalid="ignore"):
            scale = -self.position[2] / directions[..., 2]
        points = self.position + directions * scale[..., None]
        return np.where((scale > 0)[..., None], points[..., :2], np.nan)

    def _camera_rays(self, pixels: np.ndarray) -> np.ndarray:
        """`(..., 3)` camera-frame rays with z = 1 through `(..., 2)` pixels."""
        pixels = np.asarray(pixels, np.float64)
        homogeneous = np.concatenate([pixels, np.ones_like(pixels[..., :1])], axis=-1)
        return homogeneous @ np.linalg.inv(self.intrinsics).T
