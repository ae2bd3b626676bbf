"""What the placement environment shows a policy of a scene: a robot's input, as Gymnasium spaces.

The observation is built from the fields of a `SceneRecord` that hold no ground truth (never its
tuples, their token indices or the oracle), so a redacted record, as the evaluation harness hands
methods, gives the same observation as the full one:

    rgb                (H, W, 3) uint8
    depth              (H, W) float32 planar depth in metres (stored as whole millimetres)
    boxes              (MAX_BOXES, 4) int32 pixel boxes (u0, v0, u1, v1) of the visible objects, ascending
                       object id (the visual tokens' order); rows past the last box are 0
    box_mask           (MAX_BOXES,) int8, 1 where `boxes` holds a box
    box_aabbs          (MAX_BOXES, 2, 3) float64 world AABB [[xmin, ymin, zmin], [xmax, ymax, zmax]] of each
                       boxed object, metres (the table top is z = 0); rows past the last box are 0
    instruction        str
    held_footprint     (2,) float64 half-extents (hx, hy) of the held object's upright footprint, metres
    camera_intrinsics  (3, 3) float64 K
    camera_pose        (4, 4) float64 world_from_camera (OpenCV camera axes, table frame)
"""

from __future__ import annotations

import string

import numpy as np
from gymnasium import spaces

from ocplace.errors import DatasetError
from ocplace.sim.dataset.records import SceneRecord
from ocplace.sim.pinhole import PinholeCamera
from ocplace.sim.scene import NUM_SCENE_OBJECTS

MAX_BOXES = NUM_SCENE_OBJECTS  # every scene object visible: one box each
DEPTH_MAX = 65.535  # metres: the largest depth a scene's uint16 millimetre PNG holds
# Metres from the table's centre that bound every position the observation holds: scene objects rest on
# the 0.8 x 0.6 m table (the generator redraws a scene whose objects fall off) and the camera looks down on it.
WORKSPACE_EXTENT = 2.0
MAX_FOCAL_PIXELS = 1e6  # bounds K's entries: any real camera's lie far inside
MAX_INSTRUCTION_LENGTH = 512  # characters; the benchmark's instructions stay under 200
# Instructions are ASCII sentences; Gymnasium's default Text alphabet has no space or punctuation.
INSTRUCTION_CHARACTERS = string.ascii_letters + string.digits + string.punctuation + " "


def observation_space(camera: PinholeCamera) -> spaces.Dict:
    """The observation space of scenes rendered by `camera` (its width and height fix the images')."""
    height, width = camera.height, camera.width
    pose_high = np.ones((4, 4))
    pose_high[:3, 3] = WORKSPACE_EXTENT
    pose_low = -pose_high
    pose_low[3] = 0.0  # a rigid pose's last row is 0 0 0 1
    return spaces.Dict(
        {
            "rgb": spaces.Box(0, 255, (height, width, 3), np.uint8),
            "depth": spaces.Box(0.0, DEPTH_MAX, (height, width), np.float32),
            "boxes": spaces.Box(0, np.tile(_image_corner(width, height), (MAX_BOXES, 1)), dtype=np.int32),
            "box_mask": spaces.MultiBinary(MAX_BOXES),
            "box_aabbs": spaces.Box(-WORKSPACE_EXTENT, WORKSPACE_EXTENT, (MAX_BOXES, 2, 3), np.float64),
            "instruction": spaces.Text(MAX_INSTRUCTION_LENGTH, charset=INSTRUCTION_CHARACTERS),
            "held_footprint": spaces.Box(0.0, WORKSPACE_EXTENT, (2,), np.float64),
            "camera_intrinsics": spaces.Box(-MAX_FOCAL_PIXELS, MAX_FOCAL_PIXELS, (3, 3), np.float64),
            "camera_pose": spaces.Box(pose_low, pose_high, dtype=np.float64),
        }
    )


def observation(record: SceneRecord) -> dict:
    """The observation of a scene (see the module's docstring); reads no ground truth, so redacted records work."""
    boxes = record.boxes
    if len(boxes) > MAX_BOXES:
        raise DatasetError(
            f"scene {record.id} has {len(boxes)} object boxes, more than the environment's {MAX_BOXES}; "
            "it was not made by this version of ocplace's generator"
        )
    aabb_by_id = {obj.object_id: obj.aabb for obj in record.objects}
    padded_boxes = np.zeros((MAX_BOXES, 4), np.int32)
    padded_boxes[: len(boxes)] = boxes.boxes
    aabbs = np.zeros((MAX_BOXES, 2, 3), np.float64)
    for row, object_id in enumerate(boxes.object_ids):
        aabbs[row] = aabb_by_id[int(object_id)]
    # Copies, never views of the record: a policy may write into its observation, and the record scores it.
    return {
        "rgb": np.array(record.rgb),
        "depth": np.array(record.depth),
        "boxes": padded_boxes,
        "box_mask": (np.arange(MAX_BOXES) < len(boxes)).astype(np.int8),
        "box_aabbs": aabbs,
        "instruction": record.instruction,
        "held_footprint": np.array(record.held_object.footprint_half_extents, np.float64),
        "camera_intrinsics": np.array(record.camera.intrinsics),
        "camera_pose": np.array(record.camera.world_from_camera),
    }


def _image_corner(width: int, height: int) -> np.ndarray:
    """`(4,)` int32 upper bounds of a pixel box `(u0, v0, u1, v1)`."""
    return np.asarray([width, height, width, height], np.int32)
