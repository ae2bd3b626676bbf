"""Fixed-length tuples of floats read from files (scales, extents, colours), typed by their length.

A mesh scale or a colour read from MJCF, URDF or JSON is a run of numbers of unknown length until it is checked;
these give the type checker (and the reader) the length the rest of the code relies on.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import SupportsFloat


def vec3(values: Iterable[SupportsFloat | str]) -> tuple[float, float, float]:
    """Three floats; ValueError naming the count otherwise."""
    x, y, z = _floats(values, 3)
    return x, y, z


def vec4(values: Iterable[SupportsFloat | str]) -> tuple[float, float, float, float]:
    """Four floats (an RGBA colour, a quaternion); ValueError naming the count otherwise."""
    r, g, b, a = _floats(values, 4)
    return r, g, b, a


def _floats(values: Iterable[SupportsFloat | str], count: int) -> list[float]:
    numbers = [float(value) for value in values]
    if len(numbers) != count:
        raise ValueError(f"{count} numbers are needed, got {len(numbers)}: {numbers}")
    return numbers
