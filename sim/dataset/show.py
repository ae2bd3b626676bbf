"""A picture of one dataset scene: instruction, boxes, ground-truth references, feasible region."""

from __future__ import annotations

import cv2
import numpy as np

from ocplace.sim.camera import Camera
from ocplace.sim.dataset.records import SceneRecord
from ocplace.sim.figures import draw_boxes
from ocplace.sim.metric import DEFAULT_GRID, feasible_grid

FEASIBLE_COLOUR = np.array([40, 220, 90], np.float32)


def _camera(record: SceneRecord) -> Camera:
    return Camera(width=record.camera.width, height=record.camera.height, position=tuple(record.camera.position))


def feasible_overlay(record: SceneRecord, alpha: float = 0.45) -> np.ndarray:
    """The RGB image with the oracle's feasible region painted over the table."""
    camera = _camera(record)
    feasible = feasible_grid(record.problem())
    half = DEFAULT_GRID.resolution / 2.0
    image = record.rgb.astype(np.float32)
    mask = np.zeros(record.rgb.shape[:2], np.uint8)
    for x, y in DEFAULT_GRID.cell_centres()[feasible]:
        corners = camera.table_to_pixel(np.array([[x - half, y - half], [x + half, y + half]]))
        (u0, v1), (u1, v0) = np.round(corners).astype(int)
        mask[max(v0, 0) : max(v1, 0) + 1, max(u0, 0) : max(u1, 0) + 1] = 1
    image[mask == 1] = (1 - alpha) * image[mask == 1] + alpha * FEASIBLE_COLOUR
    return image.astype(np.uint8)


def scene_figure(record: SceneRecord) -> np.ndarray:
    """`(H + banner, W, 3)`: feasible region, labelled boxes (references in bold), oracle point."""
    labels = {obj.object_id: obj.human_name for obj in record.objects}
    references = {t.reference_object_id for t in record.true_tuples()}
    canvas = draw_boxes(feasible_overlay(record), record.boxes, labels)
    for object_id, (u0, v0, u1, v1) in zip(record.boxes.object_ids, record.boxes.boxes, strict=True):
        if object_id in references:
            cv2.rectangle(canvas, (int(u0) - 2, int(v0) - 2), (int(u1) + 1, int(v1) + 1), (255, 255, 255), 2)
    u, v = _camera(record).table_to_pixel(record.true_placement())
    cv2.drawMarker(canvas, (int(round(u)), int(round(v))), (255, 0, 255), cv2.MARKER_TILTED_CROSS, 18, 3)
    lines = [
        f"{record.id} ({record.level}): {record.instruction}",
        "truth: "
        + "; ".join(f"{t.relation} of {t.reference_name} (token {t.token_index})" for t in record.true_tuples())
        + f" | held: {record.held_object.human_name}",
    ]
    banner = np.full((22 * len(lines) + 8, canvas.shape[1], 3), 255, np.uint8)
    for row, text in enumerate(lines):
        cv2.putText(banner, text, (6, 20 + 22 * row), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    return np.concatenate([banner, canvas], axis=0)
