"""EfficientNet-Lite's architecture as data: the variants, their stages and blocks after scaling.

Apart from `models/efficientnet.py` (the Flax network) so that a recipe naming a trunk (`OfflineConfig`)
is checked without importing JAX: a bad `--set` fails in a fraction of a second.
"""

from __future__ import annotations

import dataclasses
import functools
import math

from ocplace.errors import BackboneError

STEM_WIDTH = 32
HEAD_WIDTH = 1280
NUM_CLASSES = 1000
PIXEL_MEAN = 127.0
PIXEL_STD = 128.0


@dataclasses.dataclass(frozen=True)
class Stage:
    """A run of `repeats` MBConv blocks; only the first one strides and changes width."""

    repeats: int
    kernel: int
    stride: int
    expand: int
    out: int


# EfficientNet-Lite0 (efficientnet_lite_builder.py), before width and depth scaling.
BASE_STAGES = (
    Stage(1, 3, 1, 1, 16),
    Stage(2, 3, 2, 6, 24),
    Stage(2, 5, 2, 6, 40),
    Stage(3, 3, 2, 6, 80),
    Stage(3, 5, 1, 6, 112),
    Stage(4, 5, 2, 6, 192),
    Stage(1, 3, 1, 6, 320),
)


@dataclasses.dataclass(frozen=True)
class BlockConfig:
    """One MBConv block after scaling."""

    kernel: int
    stride: int
    expand: int
    inp: int
    out: int

    @property
    def hidden(self) -> int:
        return self.inp * self.expand

    @property
    def residual(self) -> bool:
        return self.stride == 1 and self.inp == self.out


@dataclasses.dataclass(frozen=True)
class LiteConfig:
    """A Lite variant: width and depth multipliers and its training resolution."""

    name: str
    width: float
    depth: float
    resolution: int

    @functools.cached_property
    def blocks(self) -> tuple[BlockConfig, ...]:
        blocks, inp = [], STEM_WIDTH
        for index, stage in enumerate(BASE_STAGES):
            fixed = index in (0, len(BASE_STAGES) - 1)  # Lite keeps the first and last stage's depth
            repeats = stage.repeats if fixed else math.ceil(self.depth * stage.repeats)
            out = round_filters(stage.out, self.width)
            for repeat in range(repeats):
                blocks.append(BlockConfig(stage.kernel, stage.stride if repeat == 0 else 1, stage.expand, inp, out))
                inp = out
        return tuple(blocks)


VARIANTS = {
    "lite0": LiteConfig("lite0", 1.0, 1.0, 224),
    "lite1": LiteConfig("lite1", 1.0, 1.1, 240),
    "lite2": LiteConfig("lite2", 1.1, 1.2, 260),
}


def round_filters(filters: int, width: float, divisor: int = 8) -> int:
    """TF's channel rounding: scale, round to a multiple of `divisor`, never more than 10% down."""
    scaled = filters * width
    rounded = max(divisor, int(scaled + divisor / 2) // divisor * divisor)
    return int(rounded + divisor if rounded < 0.9 * scaled else rounded)


def config(variant: str) -> LiteConfig:
    try:
        return VARIANTS[variant]
    except KeyError:
        raise BackboneError(f"unknown EfficientNet variant {variant!r}; use one of {sorted(VARIANTS)}") from None


def block_names(variant: str = "lite0") -> tuple[str, ...]:
    """Top-level parameter names in forward order: `stem`, `blocks_00`, ..., `head`, `classifier`."""
    count = len(config(variant).blocks)
    return ("stem", *(f"blocks_{i:02d}" for i in range(count)), "head", "classifier")
