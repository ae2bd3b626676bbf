"""The basic colour terms as HSV ranges: which pixels a colour word names.

Hue is OpenCV's (0-180, half degrees; red's range wraps below 0), saturation and value 0-255.
Pretraining paints primitives and recolours rendered objects with them (`train.pretrain.colours`);
its recipes name the terms they use.
"""

from __future__ import annotations

import dataclasses


@dataclasses.dataclass(frozen=True)
class ColourTerm:
    """A colour word and the HSV box it names; `hue` None for black, white and grey."""

    name: str
    hue: tuple[float, float] | None
    saturation: tuple[float, float]
    value: tuple[float, float]


COLOUR_TERMS = {
    term.name: term
    for term in (
        ColourTerm("black", None, (0, 30), (25, 50)),
        ColourTerm("white", None, (0, 15), (225, 250)),
        ColourTerm("red", (-5, 3), (185, 240), (150, 215)),
        ColourTerm("green", (50, 70), (150, 230), (110, 190)),
        ColourTerm("yellow", (25, 31), (180, 240), (215, 250)),
        ColourTerm("blue", (104, 116), (165, 240), (140, 215)),
        ColourTerm("brown", (9, 16), (150, 210), (75, 120)),
        ColourTerm("orange", (11, 16), (210, 250), (215, 250)),
        ColourTerm("pink", (162, 172), (70, 125), (215, 250)),
        ColourTerm("purple", (133, 147), (125, 200), (110, 180)),
        ColourTerm("grey", None, (0, 15), (115, 160)),
    )
}
BASIC_COLOURS = tuple(COLOUR_TERMS)
