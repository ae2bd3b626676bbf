"""The top-down RGB-D camera (docs/design.md#conventions): a pinhole model of a RealSense L515 depth stream.

Pixel coordinates are (u, v) with u to the right and v down, pixel centres at integers, so
the principal point of a 640x480 image is (319.5, 239.5). Depth is planar: the distance along
the optical axis, not along the ray.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

# Columns are the camera's x (image right), y (image down) and z (optical axis) in the world
# frame: image right is +x, image up is +y, and the camera looks straight down.
_LOOK_DOWN = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]]).T


@dataclasses.dataclass(frozen=True)
class Camera:
    width: int = 640
    height: int = 480
    fov_x_deg: float = 70.0
    position: tuple[float, float, float] = (0.0, 0.0, 0.60)  # metres, above the table centre

    @property
    def fx(self) -> float:
        return (self.width / 2.0) / math.tan(math.radians(self.fov_x_deg) / 2.0)

    @property
    def fy(self) -> float:
        return self.fx

    @property
    def cx(self) -> float:
        return (self.width - 1) / 2.0

    @property
    def cy(self) -> float:
        return (self.height - 1) / 2.0

    @property
    def fov_y_deg(self) -> float:
        return math.degrees(2.0 * math.atan((self.height / 2.0) / self.fy))

    @property
    def intrinsics(self) -> np.ndarray:
        """`(3, 3)` matrix K."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def rotation(self) -> np.ndarray:
        """`(3, 3)` world-from-camera rotation (OpenCV camera axes)."""
        return _LOOK_DOWN

    @property
    def world_from_camera(self) -> np.ndarray:
        """`(4, 4)` pose of the camera in the world frame."""
        pose = np.eye(4)
        pose[:3, :3] = self.rotation
        pose[:3, 3] = self.position
        return pose

    def world_to_camera(self, points: np.ndarray) -> np.ndarray:
        """`(..., 3)` world points -> `(..., 3)` camera-frame points."""
        return (np.asarray(points, dtype=np.float64) - self.position) @ self.rotation

    def world_to_pixel(self, points: np.ndarray) -> np.ndarray:
        """`(..., 3)` world points -> `(..., 2)` pixel coordinates (u, v)."""
        camera_points = self.world_to_camera(points)
        z = camera_points[..., 2]
        u = self.fx * camera_points[..., 0] / z + self.cx
        v = self.fy * camera_points[..., 1] / z + self.cy
        return np.stack([u, v], axis=-1)

    def pixel_to_world(self, pixels: np.ndarray, depth: np.ndarray) -> np.ndarray:
        """`(..., 2)` pixels (u, v) with `(...)` planar depth in metres -> `(..., 3)` world points."""
        pixels = np.asarray(pixels, dtype=np.float64)
        depth = np.asarray(depth, dtype=np.float64)
        x = (pixels[..., 0] - self.cx) / self.fx * depth
        y = (pixels[..., 1] - self.cy) / self.fy * depth
        camera_points = np.stack([x, y, depth], axis=-1)
        return camera_points @ self.rotation.T + np.asarray(self.position)

    def table_to_pixel(self, xy: np.ndarray) -> np.ndarray:
        """`(..., 2)` points on the table plane z = 0 -> `(..., 2)` pixels."""
        xy = np.asarray(xy, dtype=np.float64)
        return self.world_to_pixel(np.concatenate([xy, np.zeros_like(xy[..., :1])], axis=-1))

    def to_json(self) -> dict:
        """Everything a reader needs to use the images without this project."""
        return {
            "width": self.width,
            "height": self.height,
            "fx": self.fx,
            "fy": self.fy,
            "cx": self.cx,
            "cy": self.cy,
            "intrinsics": self.intrinsics.tolist(),
            "world_from_camera": self.world_from_camera.tolist(),
            "depth": "planar, metres (stored as uint16 millimetres)",
            "axes": "world: +x image right, +y image up, +z up; camera: OpenCV (x right, y down, z forward)",
        }


DEFAULT_CAMERA = Camera()
