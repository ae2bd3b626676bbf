"""A scene of the robot's own, from files: an RGB image, a depth image (or `.npy` of metres), optionally a
segmentation, and a camera; what `ocplace place` reads before the policy places."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from ocplace.errors import PolicyInputError
from ocplace.models.policy import SceneInput, check_depth
from ocplace.sim.pinhole import PinholeCamera


def read_scene_input(
    rgb: Path,
    depth: Path,
    segmentation: Path | None,
    camera,
    instruction: str,
    held_footprint: tuple[float, float],
) -> SceneInput:
    """The `SceneInput` of those files (`camera`: a camera JSON file or anything `PinholeCamera.from_any` takes);
    PolicyInputError naming a file that cannot be read."""
    image = np.ascontiguousarray(_read_image(rgb, cv2.IMREAD_COLOR)[..., ::-1])
    metres = check_depth(read_npy(depth) if depth.suffix == ".npy" else _read_image(depth, cv2.IMREAD_UNCHANGED))
    segments = _read_image(segmentation, cv2.IMREAD_UNCHANGED).astype(np.int32) if segmentation else None
    return SceneInput(
        image, metres, segments, instruction, held_footprint, PinholeCamera.from_any(camera), name=rgb.name
    )


def _read_image(path: Path, flags: int) -> np.ndarray:
    image = cv2.imread(str(path), flags)
    if image is None:
        raise PolicyInputError(f"cannot read the image {path}")
    return image


def read_npy(path: Path) -> np.ndarray:
    """A depth `.npy` of numbers; never unpickles (a pickled array could run any code)."""
    try:
        return np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as error:
        raise PolicyInputError(
            f"cannot read the depth {path} as a .npy array of numbers ({error}); save a float "
            "array of metres with numpy.save"
        ) from None
