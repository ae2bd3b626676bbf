"""Object boxes from a segmentation image, and square crops around them.

Boxes are `(u0, v0, u1, v1)` in pixel-edge coordinates: the box covers columns u0..u1-1 and rows
v0..v1-1, so its width is u1 - u0.
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np

MIN_VISIBLE_PIXELS = 200


@dataclasses.dataclass(frozen=True)
class Boxes:
    object_ids: np.ndarray  # (N,) int32 segmentation ids, ascending
    boxes: np.ndarray  # (N, 4) int32 (u0, v0, u1, v1)
    pixel_counts: np.ndarray  # (N,) int64 visible pixels per object

    def __len__(self) -> int:
        return len(self.object_ids)

    def box_of(self, object_id: int) -> np.ndarray | None:
        """`(4,)` box of `object_id`, or None when the object got no box."""
        matches = np.flatnonzero(self.object_ids == object_id)
        return self.boxes[matches[0]] if len(matches) else None


def boxes_from_segmentation(segmentation: np.ndarray, min_pixels: int = MIN_VISIBLE_PIXELS) -> Boxes:
    """One box per object id > 0 with at least `min_pixels` visible pixels."""
    ids, counts = np.unique(segmentation[segmentation > 0], return_counts=True)
    keep = counts >= min_pixels
    ids, counts = ids[keep], counts[keep]
    boxes = np.zeros((len(ids), 4), dtype=np.int32)
    for row, object_id in enumerate(ids):
        vs, us = np.nonzero(segmentation == object_id)
        boxes[row] = (us.min(), vs.min(), us.max() + 1, vs.max() + 1)
    return Boxes(ids.astype(np.int32), boxes, counts.astype(np.int64))


def square_crop(image: np.ndarray, box: np.ndarray, padding: float = 0.1, size: int | None = None) -> np.ndarray:
    """A square crop centred on `box`, its side the box's longer side plus `padding` on each side.

    Parts of the square outside the image are filled with the image's border pixels so the crop
    never shows artificial black bars. With `size`, the crop is resized to `(size, size)`.
    """
    u0, v0, u1, v1 = (float(x) for x in box)
    side = max(u1 - u0, v1 - v0) * (1.0 + 2.0 * padding)
    side = max(int(round(side)), 1)
    centre_u, centre_v = (u0 + u1) / 2.0, (v0 + v1) / 2.0
    left, top = int(round(centre_u - side / 2.0)), int(round(centre_v - side / 2.0))
    height, width = image.shape[:2]
    pad = max(0, -left, -top, left + side - width, top + side - height)
    if pad:
        image = cv2.copyMakeBorder(image, pad, pad, pad, pad, cv2.BORDER_REPLICATE)
    crop = image[top + pad : top + pad + side, left + pad : left + pad + side]
    if size is not None:
        interpolation = cv2.INTER_AREA if side > size else cv2.INTER_CUBIC
        crop = cv2.resize(crop, (size, size), interpolation=interpolation)
    return np.ascontiguousarray(crop)
