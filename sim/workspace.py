"""The table: the placement area, its 3x3 grid, and where scene objects are dropped.

World frame (docs/design.md#conventions): table top is z = 0, +x right in the image, +y away from the viewer.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from ocplace.serial import bounded


@dataclasses.dataclass(frozen=True)
class Table:
    """The placement area: the table top rectangle, centred on the world origin."""

    half_extents: tuple[float, float] = bounded((0.40, 0.30), 0.05, 5.0)  # metres, (x, y)
    thickness: float = bounded(0.04, 0.001, 1.0)
    drop_half_extents: tuple[float, float] = bounded((0.24, 0.16), 0.01, 5.0)  # central area objects are dropped over

    def problems(self) -> list[str]:
        if any(drop > half for drop, half in zip(self.drop_half_extents, self.half_extents, strict=True)):
            return [f"drop_half_extents {self.drop_half_extents} must lie within half_extents {self.half_extents}"]
        return []

    @property
    def bounds(self) -> np.ndarray:
        """`(2, 2)` array `[[xmin, ymin], [xmax, ymax]]`."""
        hx, hy = self.half_extents
        return np.array([[-hx, -hy], [hx, hy]])

    @property
    def cell_size(self) -> np.ndarray:
        """`(2,)` size of one cell of the 3x3 grid."""
        return 2.0 * np.asarray(self.half_extents) / 3.0

    @classmethod
    def from_dict(cls, fields: dict) -> Table:
        """The table of `dataclasses.asdict(table)`, also after a JSON round trip (lists back to tuples)."""
        values: dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v for k, v in fields.items()}
        return cls(**values)

    def cell_bounds(self, column: int, row: int) -> np.ndarray:
        """`(2, 2)` bounds of grid cell (column 0..2 left to right, row 0..2 front to back)."""
        low = self.bounds[0] + self.cell_size * np.array([column, row])
        return np.stack([low, low + self.cell_size])


DEFAULT_TABLE = Table()
