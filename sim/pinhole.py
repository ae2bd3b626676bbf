"""A pinhole camera from intrinsics and a pose: what a robot's RGB-D input comes with.

`sim.camera.Camera` is the simulator's fixed top-down camera; this is the general model the
policy accepts (any intrinsics, any pose), built from the `camera` of a dataset scene.json, a
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

# A camera JSON may also repeat these entries of K (`sim.camera.Camera.to_json` does): they must agree.
_K_ENTRIES = {"fx": (0, 0), "fy": (1, 1), "cx": (0, 2), "cy": (1, 2)}
_FIELDS_HELP = (
    "a camera JSON holds intrinsics (3x3 K: fx, fy > 0 pixels on the diagonal, the principal point "
    "cx, cy in the last column, last row 0 0 1), world_from_camera (4x4 rigid pose in the table "
    "frame, metres), width and height (pixels)"
)


@dataclasses.dataclass(frozen=True, eq=False)
class PinholeCamera:
    """Raises PolicyInputError on construction when a field cannot describe a pinhole camera."""

    intrinsics: np.ndarray  # (3, 3) K
    world_from_camera: np.ndarray  # (4, 4) pose of the camera in the world (table) frame
    width: int
    height: int

    def __post_init__(self):
        intrinsics = _finite_matrix("intrinsics", self.intrinsics, (3, 3))
        pose = _finite_matrix("world_from_camera", self.world_from_camera, (4, 4))
        _check_intrinsics(intrinsics)
        _check_pose(pose)
        object.__setattr__(self, "intrinsics", intrinsics)
        object.__setattr__(self, "world_from_camera", pose)
        object.__setattr__(self, "width", _pixels("width", self.width))
        object.__setattr__(self, "height", _pixels("height", self.height))

    @classmethod
    def from_any(cls, camera) -> PinholeCamera:
        """A PinholeCamera from itself, a `sim.camera.Camera`, a camera dict or a JSON file path."""
        if isinstance(camera, PinholeCamera):
            return camera
        if isinstance(camera, (str, Path)):
            return cls.from_json(_read_json(Path(camera)))
        if isinstance(camera, dict):
            return cls.from_json(camera)
        if hasattr(camera, "intrinsics") and hasattr(camera, "world_from_camera"):
            return cls(camera.intrinsics, camera.world_from_camera, camera.width, camera.height)
        raise PolicyInputError(
            f"cannot read a camera from {type(camera).__name__}; pass a PinholeCamera, a "
            "sim.camera.Camera or a dict with intrinsics, world_from_camera, width, height"
        )

    @classmethod
    def from_json(cls, fields: dict) -> PinholeCamera:
        """From a dataset scene.json's `camera` (`sim.camera.Camera.to_json`) or `to_json`'s output."""
        if not isinstance(fields, dict):
            raise PolicyInputError(f"a camera JSON is an object, not {type(fields).__name__}; {_FIELDS_HELP}")
        missing = [k for k in ("intrinsics", "world_from_camera", "width", "height") if k not in fields]
        if missing:
            raise PolicyInputError(f"camera JSON lacks {missing}; {_FIELDS_HELP}")
        camera = cls(fields["intrinsics"], fields["world_from_camera"], fields["width"], fields["height"])
        _check_repeated_entries(fields, camera.intrinsics)
        return camera

    def to_json(self) -> dict:
        return {
            "intrinsics": self.intrinsics.tolist(),
            "world_from_camera": self.world_from_camera.tolist(),
            "width": self.width,
            "height": self.height,
        }

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


def _read_json(path: Path):
    try:
        return json.loads(path.read_text())
    except OSError as error:
        raise PolicyInputError(f"cannot read the camera file {path}: {error.strerror or error}") from None
    except ValueError as error:  # truncated or not JSON, or not UTF-8
        raise PolicyInputError(f"the camera file {path} is not valid JSON ({error}); {_FIELDS_HELP}") from None


def _finite_matrix(name: str, value, shape: tuple[int, int]) -> np.ndarray:
    try:
        matrix = np.asarray(value, np.float64)
    except (TypeError, ValueError):
        matrix = None
    if matrix is None or matrix.shape != shape or not np.all(np.isfinite(matrix)):
        raise PolicyInputError(
            f"camera {name} must be a {shape[0]}x{shape[1]} matrix of finite numbers, got "
            f"{_show(value)}; {_FIELDS_HELP}"
        )
    return matrix


def _check_intrinsics(k: np.ndarray) -> None:
    for name in ("fx", "fy"):
        value = k[_K_ENTRIES[name]]
        if value <= 0:  # a negative focal length mirrors the image: placements would land on the wrong side
            raise PolicyInputError(
                f"camera focal length {name} (intrinsics{list(_K_ENTRIES[name])}) is {value:g}; "
                "it must be a positive number of pixels (the simulator's camera has 457.0)"
            )
    if k[1, 0] != 0 or not np.array_equal(k[2], [0.0, 0.0, 1.0]):
        raise PolicyInputError(
            f"camera intrinsics {k.tolist()} is not a pinhole K, which reads [[fx, skew, cx], [0, fy, cy], [0, 0, 1]]"
        )


def _check_pose(pose: np.ndarray) -> None:
    rotation = pose[:3, :3]
    if not np.array_equal(pose[3], [0.0, 0.0, 0.0, 1.0]):
        raise PolicyInputError(
            f"camera world_from_camera's last row is {pose[3].tolist()}; a rigid pose ends in 0 0 0 1"
        )
    # A reflection (determinant -1) is orthonormal too, but swaps left and right in the table frame.
    if not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-6) or np.linalg.det(rotation) < 0:
        raise PolicyInputError(
            "camera world_from_camera's rotation block (3x3, top left) is not a rotation: it must "
            "be orthonormal with determinant +1"
        )


def _pixels(name: str, value) -> int:
    whole = (
        isinstance(value, (int, float, np.integer, np.floating))
        and not isinstance(value, (bool, np.bool_))
        and float(value).is_integer()
    )
    if not whole or value <= 0:
        raise PolicyInputError(
            f"camera {name} is {_show(value)}; it must be a positive whole number of pixels (e.g. 640 wide, 480 high)"
        )
    return int(value)


def _check_repeated_entries(fields: dict, k: np.ndarray) -> None:
    for name, index in _K_ENTRIES.items():
        if name not in fields:
            continue
        value = fields[name]
        if not isinstance(value, (int, float)) or isinstance(value, bool) or not np.isclose(value, k[index]):
            raise PolicyInputError(
                f"camera JSON {name} = {_show(value)} disagrees with intrinsics{list(index)} = "
                f"{k[index]:g}; edit both, or drop {name}"
            )


def _show(value) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."
