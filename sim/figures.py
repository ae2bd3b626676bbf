"""Pictures of scenes for people: RGB with labelled boxes, depth and segmentation side by side."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from ocplace.paths import atomic_path
from ocplace.sim.boxes import Boxes


def _palette(count: int) -> np.ndarray:
    """`(count, 3)` distinct uint8 colours; index 0 is dark grey for the background."""
    hues = (np.arange(count) * 0.61803398875 % 1.0 * 179).astype(np.uint8)
    hsv = np.stack([hues, np.full(count, 200, np.uint8), np.full(count, 255, np.uint8)], axis=-1)
    colours = cv2.cvtColor(hsv[None], cv2.COLOR_HSV2RGB)[0]
    colours[0] = (40, 40, 40)
    return colours


def draw_boxes(rgb: np.ndarray, boxes: Boxes, labels: dict[int, str]) -> np.ndarray:
    """A copy of `rgb` with each box outlined and labelled with `labels[object_id]`."""
    canvas = rgb.copy()
    colours = _palette(int(max(boxes.object_ids, default=0)) + 1)
    for object_id, (u0, v0, u1, v1) in zip(boxes.object_ids, boxes.boxes, strict=True):
        colour = tuple(int(c) for c in colours[object_id])
        cv2.rectangle(canvas, (int(u0), int(v0)), (int(u1) - 1, int(v1) - 1), colour, 2)
        text = f"{object_id}: {labels.get(int(object_id), '?')}"
        (width, height), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, 0.45, 1)
        top = max(int(v0) - height - 6, 0)
        cv2.rectangle(canvas, (int(u0), top), (int(u0) + width + 4, top + height + 6), colour, -1)
        cv2.putText(
            canvas, text, (int(u0) + 2, top + height + 2), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA
        )
    return canvas


def colourise_depth(depth: np.ndarray, near: float | None = None, far: float | None = None) -> np.ndarray:
    """`(H, W)` metres -> `(H, W, 3)` uint8, near bright; the range defaults to the 1st-99th percentile."""
    near = float(np.percentile(depth, 1)) if near is None else near
    far = float(np.percentile(depth, 99)) if far is None else far
    scaled = np.clip((far - depth) / max(far - near, 1e-6), 0.0, 1.0)
    return cv2.cvtColor(cv2.applyColorMap((scaled * 255).astype(np.uint8), cv2.COLORMAP_VIRIDIS), cv2.COLOR_BGR2RGB)


def colourise_segmentation(segmentation: np.ndarray) -> np.ndarray:
    return _palette(int(segmentation.max()) + 1)[segmentation]


def scene_panel(
    rgb: np.ndarray, depth: np.ndarray, segmentation: np.ndarray, boxes: Boxes, labels: dict[int, str], title: str = ""
) -> np.ndarray:
    """`(H + title, 3 W, 3)` picture: labelled RGB | depth | segmentation."""
    panels = [draw_boxes(rgb, boxes, labels), colourise_depth(depth), colourise_segmentation(segmentation)]
    picture = np.concatenate(panels, axis=1)
    if title:
        banner = np.full((28, picture.shape[1], 3), 255, np.uint8)
        cv2.putText(banner, title, (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 1, cv2.LINE_AA)
        picture = np.concatenate([banner, picture], axis=0)
    return picture


def save_png(path: str | Path, image: np.ndarray) -> Path:
    """Writes an RGB (or single-channel) image atomically as PNG."""
    path = Path(path)
    ok, encoded = cv2.imencode(".png", image[..., ::-1] if image.ndim == 3 else image)
    if not ok:
        raise OSError(f"could not encode {path} as PNG")
    with atomic_path(path) as tmp:
        tmp.write_bytes(encoded.tobytes())
    return path


def labelled_scene(scene, library, title: str = "") -> np.ndarray:
    """The picture of a `RenderedScene`, boxes labelled with the objects' human names."""
    from ocplace.sim.boxes import boxes_from_segmentation

    boxes = boxes_from_segmentation(scene.segmentation)
    labels = {obj.object_id: library.get(obj.name).human_name for obj in scene.objects}
    return scene_panel(scene.rgb, scene.depth, scene.segmentation, boxes, labels, title)
