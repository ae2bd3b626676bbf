"""How an image becomes a backbone's input: CLIP's shortest-edge resize, centre crop and normalisation, as numbers.

A leaf of `ocplace.models` (no JAX), so that a backbone's configuration (`offline_config.py`) can name its
preprocessing without importing the backbones.
"""

from __future__ import annotations

import dataclasses

from ocplace.errors import BackboneError
from ocplace.sim.vectors import vec3


@dataclasses.dataclass(frozen=True)
class ImagePreprocessing:
    """CLIPImageProcessor's steps: shortest edge -> `resize`, centre crop, rescale, normalise."""

    resize: int  # target length of the shortest edge
    crop: tuple[int, int]  # (height, width) of the centre crop
    mean: tuple[float, float, float]
    std: tuple[float, float, float]
    resample: int  # PIL filter id (3 = bicubic, CLIP's)

    @classmethod
    def from_processor(cls, processor) -> ImagePreprocessing:
        size = processor.size
        if not (processor.do_resize and processor.do_center_crop and "shortest_edge" in size):
            raise BackboneError("only CLIP-style preprocessing (shortest-edge resize, centre crop) is supported")
        crop = processor.crop_size
        return cls(
            int(size["shortest_edge"]),
            (int(crop["height"]), int(crop["width"])),
            vec3(processor.image_mean),
            vec3(processor.image_std),
            int(processor.resample),
        )
