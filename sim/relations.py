"""The nine canonical spatial relations and their geometry (docs/design.md#relations-and-instructions).

Text phrases for each relation live with the instruction language; this module holds only
what the geometry needs, so the metric, the sampler and the generator share one definition.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

_D = 1.0 / math.sqrt(2.0)


@dataclasses.dataclass(frozen=True)
class Relation:
    name: str
    direction: tuple[float, float] | None  # unit (x, y); None for "middle" (table only)
    columns: tuple[int, ...]  # table grid columns of the region, 0 = left
    rows: tuple[int, ...]  # table grid rows of the region, 0 = front (bottom of image)

    @property
    def applies_to_objects(self) -> bool:
        return self.direction is not None


RELATIONS: tuple[Relation, ...] = (
    Relation("left", (-1.0, 0.0), (0,), (0, 1, 2)),
    Relation("right", (1.0, 0.0), (2,), (0, 1, 2)),
    Relation("back", (0.0, 1.0), (0, 1, 2), (2,)),
    Relation("front", (0.0, -1.0), (0, 1, 2), (0,)),
    Relation("middle", None, (1,), (1,)),
    Relation("back left", (-_D, _D), (0,), (2,)),
    Relation("back right", (_D, _D), (2,), (2,)),
    Relation("front left", (-_D, -_D), (0,), (0,)),
    Relation("front right", (_D, -_D), (2,), (0,)),
)
RELATION_NAMES: tuple[str, ...] = tuple(r.name for r in RELATIONS)
OBJECT_RELATION_NAMES: tuple[str, ...] = tuple(r.name for r in RELATIONS if r.applies_to_objects)
_BY_NAME = {r.name: r for r in RELATIONS}


def relation(name: str) -> Relation:
    """The canonical relation called `name`; raises KeyError naming the valid names."""
    try:
        return _BY_NAME[name]
    except KeyError:
        raise KeyError(f"unknown relation {name!r}; canonical relations are {RELATION_NAMES}") from None


def relation_index(name: str) -> int:
    return RELATION_NAMES.index(relation(name).name)


def direction_table() -> np.ndarray:
    """`(9, 2)` unit directions in RELATION_NAMES order; zeros for "middle"."""
    return np.array([r.direction or (0.0, 0.0) for r in RELATIONS], dtype=np.float64)


def cell_table() -> np.ndarray:
    """`(9, 3, 3)` boolean masks `[relation, column, row]` of each relation's table region."""
    masks = np.zeros((len(RELATIONS), 3, 3), dtype=bool)
    for index, r in enumerate(RELATIONS):
        masks[index][np.ix_(r.columns, r.rows)] = True
    return masks
