"""Colours drawn from the basic colour terms (`sim.colour_terms`), and recolouring an object's pixels.

The same ranges paint the primitives (a material colour) and recolour rendered objects (pixels),
so "blue" means one thing in both.
"""

from __future__ import annotations

from collections.abc import Mapping

import cv2
import numpy as np

from ocplace.sim.colour_terms import COLOUR_TERMS, ColourTerm

# Recoloured values keep the object's shading and print as a share of its bright level, squeezed
# into [VALUE_FLOOR, 1] so that dark print does not turn a "white" object black.
VALUE_FLOOR = 0.45
BRIGHT_PERCENTILE = 90


def sample_hsv(term: ColourTerm, rng: np.random.Generator) -> np.ndarray:
    """float `(3,)`: one OpenCV HSV colour inside the term's box."""
    hue = rng.uniform(*term.hue) % 180 if term.hue is not None else 0.0
    return np.array([hue, rng.uniform(*term.saturation), rng.uniform(*term.value)])


def hsv_to_rgb(hsv: np.ndarray) -> np.ndarray:
    """float `(3,)` OpenCV HSV -> float `(3,)` RGB in [0, 1]."""
    pixel = np.asarray(hsv, np.float32).reshape(1, 1, 3) * np.array([2.0, 1 / 255, 1 / 255], np.float32)
    return cv2.cvtColor(pixel, cv2.COLOR_HSV2RGB).reshape(3)


def recolour_objects(
    rgb: np.ndarray, segmentation: np.ndarray, targets: Mapping[int, str], rng: np.random.Generator
) -> np.ndarray:
    """uint8 `(H, W, 3)`: `rgb` with the pixels of each object id in `targets` recoloured to its term.

    Hue and saturation are set to a colour drawn in the term's box; value keeps the object's own
    shading and print relative to its bright level. Pixels of other ids are left exactly as they were.
    """
    hsv = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV).astype(np.float32)
    for object_id, colour in targets.items():
        mask = segmentation == object_id
        if not mask.any():
            continue
        hue, saturation, value = sample_hsv(COLOUR_TERMS[colour], rng)
        hue = round(hue) % 180  # 8-bit OpenCV hue stops at 179
        own = hsv[..., 2][mask]
        relative = np.clip(own / max(np.percentile(own, BRIGHT_PERCENTILE), 1.0), 0.0, 1.15)
        hsv[mask] = np.stack(
            [
                np.full_like(own, hue),
                np.full_like(own, saturation),
                np.clip(value * (VALUE_FLOOR + (1 - VALUE_FLOOR) * relative), 0, 255),
            ],
            axis=1,
        )
    recoloured = cv2.cvtColor(np.round(hsv).astype(np.uint8), cv2.COLOR_HSV2RGB)
    outside = ~np.isin(segmentation, list(targets))
    recoloured[outside] = rgb[outside]  # the HSV round trip is not exact: keep the rest bit for bit
    return recoloured
