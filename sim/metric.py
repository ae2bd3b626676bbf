"""The benchmark's success metric (docs/design.md#success-metric) and the oracle's feasible-region grid.

A placement p is the x-y centre of the held object. It succeeds iff every grounded tuple holds
and the held object's footprint (an axis-aligned rectangle with half-extents h centred at p) lies
inside the table top and overlaps the interior of no scene object's AABB (touching is allowed).

One implementation serves NumPy and JAX (`xp=np` or `xp=jax.numpy`), so both give the same
booleans on the same inputs. Arithmetic is float32 and written so that the result does not
depend on how a compiler fuses it (see docs/placement.md, "Exact arithmetic"):
- every comparison that decides a cone is an exact comparison (no rounding can flip it);
- squares are sums of exact partial products, so fused multiply-add gives the same bits;
- subnormal intermediates are flushed to zero explicitly, as XLA on CPU does implicitly.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np

from ocplace.errors import InvalidPlacementProblem, NoFeasiblePlacement
from ocplace.serial import bounded
from ocplace.sim import relations
from ocplace.sim.workspace import DEFAULT_TABLE, Table
from ocplace.vocabulary import MAX_PARSED_TUPLES

FLOAT = np.float32
RADIUS_MIN = 0.10  # metres, object relations
RADIUS_MAX = 0.30
_TINY = FLOAT(np.finfo(FLOAT).tiny)
_SPLIT_MASK = np.uint32(0xFFFFF000)  # keeps 12 significant bits of a float32


class PlacementProblem(NamedTuple):
    """A scene's grounded tuples and geometry; every field may carry leading scene axes `...`.

    Padded tuples (`tuple_mask` False) always hold; padded boxes (`box_mask` False) never collide.
    """

    relation: Any  # (..., K) int32, index into relations.RELATION_NAMES
    reference_is_object: Any  # (..., K) bool; False: the reference is the table
    reference_box: Any  # (..., K, 2, 2) float32 AABB [[xmin, ymin], [xmax, ymax]] of the reference
    tuple_mask: Any  # (..., K) bool
    boxes: Any  # (..., B, 2, 2) float32 AABBs of every scene object in the table plane
    box_mask: Any  # (..., B) bool
    half_extents: Any  # (..., 2) float32 half-extents (hx, hy) of the held object's footprint


@dataclasses.dataclass(frozen=True)
class GroundedTuple:
    """One `<reference, relation>` tuple after grounding."""

    relation: str
    reference_box: Any = None  # (2, 2) AABB of the reference object; None: the table


class PlacementChecks(NamedTuple):
    """Which parts of the metric hold; `S` is the placement shape (`(P,)` or `(nx, ny)`)."""

    tuples: Any  # (..., K, *S) bool, True for padded tuples
    inside_table: Any  # (..., *S) bool: the footprint lies inside the table top
    collision_free: Any  # (..., *S) bool: the footprint overlaps no box interior
    success: Any  # (..., *S) bool


class TupleGeometry(NamedTuple):
    """Each tuple's success region as rectangle AND annulus AND two half-planes through `centre`.

    A table tuple has a finite rectangle and trivial annulus and half-planes; an object tuple the
    reverse; a padded tuple is trivial everywhere.
    """

    rect_low: Any  # (..., K, 2)
    rect_high: Any  # (..., K, 2)
    centre: Any  # (..., K, 2)
    radius_sq_min: Any  # (..., K)
    radius_sq_max: Any  # (..., K)
    normals: Any  # (..., K, 2, 2) [half-plane, axis]; region: normals @ (p - centre) >= 0


def split_square(v, xp=np):
    """`v * v` as a sum of exact partial products: the same bits with or without fused multiply-add."""
    high: Any  # v's leading bits, a numpy or a JAX array as `v`
    if xp is np:
        high = (np.asarray(v, FLOAT).view(np.uint32) & _SPLIT_MASK).view(FLOAT)
    else:
        from jax import lax

        bits = lax.bitcast_convert_type(v, np.uint32) & _SPLIT_MASK
        high = lax.bitcast_convert_type(bits, FLOAT)
    low = v - high
    return (high * high + (high + high) * low) + low * low


def _flush(v, xp):
    return xp.where(xp.abs(v) < _TINY, FLOAT(0), v)


RADIUS_SQ_MIN = split_square(np.asarray([RADIUS_MIN], FLOAT))[0]
RADIUS_SQ_MAX = split_square(np.asarray([RADIUS_MAX], FLOAT))[0]


def half_plane_table() -> np.ndarray:
    """`(9, 2, 2)` normals of the two half-planes bounding each relation's 45 degree cone.

    The cone of direction d is {v : d+ . v >= 0 and d- . v >= 0} with d+- = d +- d rotated by
    90 degrees, scaled to entries in {-1, 0, 1}: so each test is an exact float comparison.
    """
    directions = relations.direction_table()
    perpendicular = np.stack([-directions[:, 1], directions[:, 0]], axis=-1)
    normals = np.stack([directions + perpendicular, directions - perpendicular], axis=1)
    scale = np.maximum(np.abs(normals).max(axis=-1, keepdims=True), 1e-12)
    return np.rint(normals / scale).astype(FLOAT)


@functools.cache
def region_table(table: Table = DEFAULT_TABLE) -> np.ndarray:
    """`(9, 2, 2)` float32 rectangle `[[xmin, ymin], [xmax, ymax]]` of each relation's table region."""
    cells = relations.cell_table()
    rects = np.zeros((len(cells), 2, 2))
    for index, mask in enumerate(cells):
        columns, rows = np.nonzero(mask)
        rects[index, 0] = table.cell_bounds(columns.min(), rows.min())[0]
        rects[index, 1] = table.cell_bounds(columns.max(), rows.max())[1]
    rects = rects.astype(FLOAT)
    rects.setflags(write=False)  # cached: shared by every caller
    return rects


def encode_problem(
    tuples: Sequence[GroundedTuple | tuple],
    boxes: Any,
    half_extents: Any,
    *,
    max_tuples: int = MAX_PARSED_TUPLES,
    max_boxes: int | None = None,
) -> PlacementProblem:
    """Pads one scene into a PlacementProblem.

    Args:
      tuples: 1..max_tuples `GroundedTuple`s (or `(relation, reference_box)` pairs).
      boxes: `(num_boxes, 2, 2)` AABBs of the scene objects.
      half_extents: `(2,)` half-extents of the held object's footprint.
      max_boxes: pad the boxes to this many (default: no padding).
    """
    grounded_tuples = [t if isinstance(t, GroundedTuple) else GroundedTuple(*t) for t in tuples]
    if not 1 <= len(grounded_tuples) <= max_tuples:
        raise InvalidPlacementProblem(
            f"a placement needs 1 to {max_tuples} tuples, got {len(grounded_tuples)}; raise max_tuples to pad more"
        )
    boxes = np.asarray(boxes, dtype=FLOAT).reshape(-1, 2, 2)
    max_boxes = len(boxes) if max_boxes is None else max_boxes
    if len(boxes) > max_boxes:
        raise InvalidPlacementProblem(f"{len(boxes)} boxes do not fit in max_boxes={max_boxes}")
    if np.any(boxes[:, 0] > boxes[:, 1]) or not np.all(np.isfinite(boxes)):
        raise InvalidPlacementProblem("boxes must be finite [[xmin, ymin], [xmax, ymax]] with min <= max")
    half_extents = np.asarray(half_extents, dtype=FLOAT).reshape(2)
    if not np.all((half_extents >= 0) & np.isfinite(half_extents)):
        raise InvalidPlacementProblem(f"footprint half-extents must be finite and >= 0, got {half_extents}")
    relation_index = np.zeros(max_tuples, np.int32)
    is_object = np.zeros(max_tuples, bool)
    reference_box = np.zeros((max_tuples, 2, 2), FLOAT)
    for index, grounded in enumerate(grounded_tuples):
        relation = relations.relation(grounded.relation)
        relation_index[index] = relations.relation_index(relation.name)
        if grounded.reference_box is not None:
            if not relation.applies_to_objects:
                raise InvalidPlacementProblem(f"relation {relation.name!r} applies to the table only, not to an object")
            box = np.asarray(grounded.reference_box, dtype=FLOAT).reshape(2, 2)
            if np.any(box[0] > box[1]) or not np.all(np.isfinite(box)):
                raise InvalidPlacementProblem(f"reference box {box.tolist()} is not a valid AABB")
            is_object[index] = True
            reference_box[index] = box
    padded_boxes = np.zeros((max_boxes, 2, 2), FLOAT)
    padded_boxes[: len(boxes)] = boxes
    return PlacementProblem(
        relation=relation_index,
        reference_is_object=is_object,
        reference_box=reference_box,
        tuple_mask=np.arange(max_tuples) < len(grounded_tuples),
        boxes=padded_boxes,
        box_mask=np.arange(max_boxes) < len(boxes),
        half_extents=half_extents,
    )


def stack_problems(problems: Sequence[PlacementProblem]) -> PlacementProblem:
    """Stacks single-scene problems along a new leading scene axis, padding tuples and boxes."""
    max_tuples = max(p.relation.shape[-1] for p in problems)
    max_boxes = max(p.boxes.shape[-3] for p in problems)

    def pad(array, size, axis):
        widths = [(0, 0)] * array.ndim
        widths[axis] = (0, size - array.shape[axis])
        return np.pad(np.asarray(array), widths)

    padded = [
        PlacementProblem(
            relation=pad(p.relation, max_tuples, 0),
            reference_is_object=pad(p.reference_is_object, max_tuples, 0),
            reference_box=pad(p.reference_box, max_tuples, 0),
            tuple_mask=pad(p.tuple_mask, max_tuples, 0),
            boxes=pad(p.boxes, max_boxes, 0),
            box_mask=pad(p.box_mask, max_boxes, 0),
            half_extents=np.asarray(p.half_extents),
        )
        for p in problems
    ]
    return PlacementProblem(*(np.stack(fields) for fields in zip(*padded)))


def scene_problem(problems: PlacementProblem, index: int) -> PlacementProblem:
    """The single-scene problem at `index` of a stacked problem, as NumPy arrays."""
    return PlacementProblem(*(np.asarray(field)[index] for field in problems))


def as_arrays(problem: PlacementProblem, xp=np) -> PlacementProblem:
    """The problem's fields as `xp` arrays of the metric's dtypes, subnormals flushed to zero."""
    return PlacementProblem(
        relation=xp.asarray(problem.relation, dtype=np.int32),
        reference_is_object=xp.asarray(problem.reference_is_object, dtype=bool),
        reference_box=_flush(xp.asarray(problem.reference_box, dtype=FLOAT), xp),
        tuple_mask=xp.asarray(problem.tuple_mask, dtype=bool),
        boxes=_flush(xp.asarray(problem.boxes, dtype=FLOAT), xp),
        box_mask=xp.asarray(problem.box_mask, dtype=bool),
        half_extents=_flush(xp.asarray(problem.half_extents, dtype=FLOAT), xp),
    )


def tuple_geometry(problem: PlacementProblem, table: Table = DEFAULT_TABLE, *, xp=np) -> TupleGeometry:
    """The success region of every tuple in the unified form of `TupleGeometry`."""
    problem = as_arrays(problem, xp)
    is_object = problem.tuple_mask & problem.reference_is_object
    is_table = problem.tuple_mask & ~problem.reference_is_object
    regions = xp.asarray(region_table(table))[problem.relation]
    inf = FLOAT(np.inf)
    box = problem.reference_box
    centre = _flush((box[..., 0, :] + box[..., 1, :]) * FLOAT(0.5), xp)
    return TupleGeometry(
        rect_low=xp.where(is_table[..., None], regions[..., 0, :], -inf),
        rect_high=xp.where(is_table[..., None], regions[..., 1, :], inf),
        centre=xp.where(is_object[..., None], centre, FLOAT(0)),
        radius_sq_min=xp.where(is_object, RADIUS_SQ_MIN, -inf),
        radius_sq_max=xp.where(is_object, RADIUS_SQ_MAX, inf),
        normals=xp.where(is_object[..., None, None], xp.asarray(half_plane_table())[problem.relation], FLOAT(0)),
    )


class _AxisTerms(NamedTuple):
    """One axis' share of each tuple's test at coordinates `(..., K, n)`."""

    in_rect: Any
    square: Any  # (p_axis - centre_axis)^2
    plane0: Any  # normal_0[axis] * (p_axis - centre_axis)
    plane1: Any


def _tuple_axis_terms(coord, geometry: TupleGeometry, axis: int, xp) -> _AxisTerms:
    coord = coord[..., None, :]
    offset = _flush(coord - geometry.centre[..., axis, None], xp)
    return _AxisTerms(
        in_rect=(coord >= geometry.rect_low[..., axis, None]) & (coord <= geometry.rect_high[..., axis, None]),
        square=split_square(offset, xp),
        plane0=geometry.normals[..., 0, axis, None] * offset,
        plane1=geometry.normals[..., 1, axis, None] * offset,
    )


def _tuples_hold(x_terms: _AxisTerms, y_terms: _AxisTerms, radius_sq_min, radius_sq_max):
    # a >= -b is the exact form of a + b >= 0: no rounding decides a cone.
    distance_sq = x_terms.square + y_terms.square
    return (
        x_terms.in_rect
        & y_terms.in_rect
        & (distance_sq >= radius_sq_min)
        & (distance_sq <= radius_sq_max)
        & (x_terms.plane0 >= -y_terms.plane0)
        & (x_terms.plane1 >= -y_terms.plane1)
    )


def _inside_table_axis(coord, half_extents, table: Table, axis: int, xp):
    half = half_extents[..., axis, None]
    low, high = FLOAT(table.bounds[0, axis]), FLOAT(table.bounds[1, axis])
    return (_flush(coord - half, xp) >= low) & (_flush(coord + half, xp) <= high)


def _box_overlap_axis(coord, problem: PlacementProblem, axis: int, xp):
    """`(..., B, n)`: the footprint's open interval overlaps the box's open interval on this axis."""
    coord = coord[..., None, :]
    half = problem.half_extents[..., None, axis, None]
    low = problem.boxes[..., :, 0, axis, None]
    high = problem.boxes[..., :, 1, axis, None]
    return (_flush(coord - half, xp) < high) & (_flush(coord + half, xp) > low)


def check_placements(placements, problem: PlacementProblem, table: Table = DEFAULT_TABLE, *, xp=np) -> PlacementChecks:
    """The metric at placements `(..., P, 2)` for a problem with leading axes `...`."""
    placements = _flush(xp.asarray(placements, dtype=FLOAT), xp)
    problem = as_arrays(problem, xp)
    geometry = tuple_geometry(problem, table, xp=xp)
    x, y = placements[..., 0], placements[..., 1]
    tuples = _tuples_hold(
        _tuple_axis_terms(x, geometry, 0, xp),
        _tuple_axis_terms(y, geometry, 1, xp),
        geometry.radius_sq_min[..., None],
        geometry.radius_sq_max[..., None],
    )
    inside = _inside_table_axis(x, problem.half_extents, table, 0, xp) & _inside_table_axis(
        y, problem.half_extents, table, 1, xp
    )
    overlap = _box_overlap_axis(x, problem, 0, xp) & _box_overlap_axis(y, problem, 1, xp)
    collision_free = ~xp.any(overlap & problem.box_mask[..., None], axis=-2)
    success = xp.all(tuples, axis=-2) & inside & collision_free
    return PlacementChecks(tuples, inside, collision_free, success)


def placement_success(placements, problem: PlacementProblem, table: Table = DEFAULT_TABLE) -> np.ndarray:
    """`(..., P)` bool: NumPy success metric at placements `(..., P, 2)`."""
    return check_placements(placements, problem, table).success


@functools.cache
def _jitted_checks():
    import jax
    import jax.numpy as jnp

    return jax.jit(functools.partial(check_placements, xp=jnp), static_argnames="table")


def check_placements_jax(placements, problem: PlacementProblem, table: Table = DEFAULT_TABLE) -> PlacementChecks:
    """Jitted JAX version of `check_placements`; same booleans on the same inputs."""
    return _jitted_checks()(placements, problem, table=table)


def placement_success_jax(placements, problem: PlacementProblem, table: Table = DEFAULT_TABLE):
    """`(..., P)` bool: JAX success metric at placements `(..., P, 2)`."""
    return check_placements_jax(placements, problem, table).success


MAX_GRID_CELLS = 1_000_000  # the sampler's (scenes, cells) arrays stay small; the default grid has 19,200


@dataclasses.dataclass(frozen=True)
class Grid:
    """A regular grid of square cells over the table top, centred on it.

    Cells are indexed `[ix, iy]` (x to the right, y away from the viewer); a cell's placement is its
    centre.
    """

    table: Table = DEFAULT_TABLE
    resolution: float = bounded(0.005, 0.001, 0.1)  # metres

    def problems(self) -> list[str]:
        """A grid the sampler can hold: at least 3x3 cells and at most MAX_GRID_CELLS."""
        cells = int(np.prod(self.shape))
        if min(self.shape) < 3 or cells > MAX_GRID_CELLS:
            return [
                f"resolution {self.resolution} on half extents {self.table.half_extents} gives {self.shape} cells; "
                f"at least 3 and at most {MAX_GRID_CELLS:,} in all are allowed"
            ]
        return []

    @property
    def shape(self) -> tuple[int, int]:
        columns, rows = (int(n) for n in np.floor(2.0 * np.asarray(self.table.half_extents) / self.resolution + 1e-6))
        return columns, rows

    @property
    def cell_area(self) -> float:
        return self.resolution**2

    def _offsets(self, axis: int) -> np.ndarray:
        count = self.shape[axis]
        margin = (2.0 * self.table.half_extents[axis] - count * self.resolution) / 2.0
        return self.table.bounds[0, axis] + margin + self.resolution * np.arange(count + 1)

    def edges(self, axis: int) -> np.ndarray:
        """`(n + 1,)` float32 cell edges along `axis` (0 = x, 1 = y)."""
        return self._offsets(axis).astype(FLOAT)

    def centres(self, axis: int) -> np.ndarray:
        """`(n,)` float32 cell centres along `axis`."""
        offsets = self._offsets(axis)
        return (offsets[:-1] + self.resolution / 2.0).astype(FLOAT)

    def cell_centres(self) -> np.ndarray:
        """`(nx, ny, 2)` float32 placement of every cell."""
        xs, ys = np.meshgrid(self.centres(0), self.centres(1), indexing="ij")
        return np.stack([xs, ys], axis=-1)


DEFAULT_GRID = Grid()


def check_grid(problem: PlacementProblem, grid: Grid = DEFAULT_GRID, *, xp=np) -> PlacementChecks:
    """The metric at every cell centre: `tuples (..., K, nx, ny)`, the rest `(..., nx, ny)`.

    Bit-for-bit the same booleans as `check_placements` at `grid.cell_centres()`: the same
    per-axis operations, combined per cell.
    """
    problem = as_arrays(problem, xp)
    geometry = tuple_geometry(problem, grid.table, xp=xp)
    x, y = xp.asarray(grid.centres(0)), xp.asarray(grid.centres(1))

    def expand(terms, axis):
        return _AxisTerms(*(t[..., :, None] if axis == 0 else t[..., None, :] for t in terms))

    tuples = _tuples_hold(
        expand(_tuple_axis_terms(x, geometry, 0, xp), 0),
        expand(_tuple_axis_terms(y, geometry, 1, xp), 1),
        geometry.radius_sq_min[..., None, None],
        geometry.radius_sq_max[..., None, None],
    )
    inside = (
        _inside_table_axis(x, problem.half_extents, grid.table, 0, xp)[..., :, None]
        & _inside_table_axis(y, problem.half_extents, grid.table, 1, xp)[..., None, :]
    )
    overlap_x = _box_overlap_axis(x, problem, 0, xp) & problem.box_mask[..., None]
    overlap_y = _box_overlap_axis(y, problem, 1, xp)
    collision_free = ~xp.any(overlap_x[..., :, None] & overlap_y[..., None, :], axis=-3)
    success = xp.all(tuples, axis=-3) & inside & collision_free
    return PlacementChecks(tuples, inside, collision_free, success)


def _fold(xp, step, init, count: int):
    """`step(count - 1, ... step(0, init))`: a Python loop under NumPy, a real loop under JAX.

    In a loop XLA reads the per-axis terms from memory; unrolled, it would fuse their
    computation into the per-cell loop and redo it for every cell.
    """
    if xp is np:
        for index in range(count):
            init = step(index, init)
        return init
    from jax import lax

    return lax.fori_loop(0, count, step, init)


def _bit_words(mask, xp):
    """`(..., n)` bool -> `(..., ceil(n / 32))` uint32: bit `j % 32` of word `j // 32` is `mask[j]`."""
    n = mask.shape[-1]
    words = -(-n // 32)
    padded = xp.concatenate([mask, xp.zeros(mask.shape[:-1] + (words * 32 - n,), bool)], axis=-1)
    bit_values = np.uint32(1) << np.arange(32, dtype=np.uint32)
    bits = padded.reshape(padded.shape[:-1] + (words, 32)).astype(np.uint32) * bit_values
    return xp.sum(bits, axis=-1, dtype=np.uint32)  # distinct powers of two: the sum is their OR


def _unpack_bits(words, n: int):
    """`(..., W)` uint32 -> `(..., n)` bool, the inverse of `_bit_words`."""
    bits = (words[..., None] >> np.arange(32, dtype=np.uint32)) & np.uint32(1)
    return bits.reshape(bits.shape[:-2] + (-1,))[..., :n] == 1


class GridTerms(NamedTuple):
    """The metric on a grid, factored into per-axis terms (the sampler's hot path).

    A cell passes iff it is inside, every `box_clear(b)` and every `tuple_holds(k)`.
    """

    inside_x: Any  # (..., nx) bool: the footprint lies within the table's x range
    inside_y: Any  # (..., ny) bool
    overlap_x: Any  # (..., B, nx) bool, False for padded boxes
    overlap_y: Any  # (..., B, ny) bool
    x_terms: _AxisTerms  # fields (..., K, nx)
    y_terms: _AxisTerms  # fields (..., K, ny)
    radius_sq_min: Any  # (..., K)
    radius_sq_max: Any

    def inside(self):
        """`(..., nx, ny)` bool: the footprint lies inside the table top."""
        return self.inside_x[..., :, None] & self.inside_y[..., None, :]

    def box_clear(self, b):
        """`(..., nx, ny)` bool: the footprint overlaps no interior point of box `b` (may be traced)."""
        return ~(self.overlap_x[..., b, :, None] & self.overlap_y[..., b, None, :])

    def fits(self, xp=np):
        """`(..., nx, ny)` bool: `inside()` and every `box_clear(b)`, through 32-cell bit masks.

        Per column, the blocked cells along y are an OR of per-box bit masks, built in a loop
        over boxes (see `_fold`), so the per-cell work is one shift whatever the number of boxes.
        """
        box_words = _bit_words(self.overlap_y, xp)  # (..., B, W)
        outside_words = _bit_words(~self.inside_y, xp)  # (..., W)
        everything = np.uint32(0xFFFFFFFF)
        blocked = xp.where(self.inside_x[..., :, None], outside_words[..., None, :], everything)

        def add_box(b, blocked):
            return blocked | xp.where(self.overlap_x[..., b, :, None], box_words[..., b, None, :], np.uint32(0))

        blocked = _fold(xp, add_box, blocked, self.overlap_x.shape[-2])  # (..., nx, W)
        return ~_unpack_bits(blocked, self.inside_y.shape[-1])

    def tuple_holds(self, k):
        """`(..., nx, ny)` bool: tuple `k` holds at each cell centre (`k` may be traced)."""
        x = _AxisTerms(*(t[..., k, :, None] for t in self.x_terms))
        y = _AxisTerms(*(t[..., k, None, :] for t in self.y_terms))
        return _tuples_hold(x, y, self.radius_sq_min[..., k, None, None], self.radius_sq_max[..., k, None, None])


def grid_terms(problem: PlacementProblem, grid: Grid = DEFAULT_GRID, *, xp=np) -> GridTerms:
    """Per-axis factors of the metric at the cell centres of `grid`; same booleans as `check_grid`."""
    problem = as_arrays(problem, xp)
    geometry = tuple_geometry(problem, grid.table, xp=xp)
    x, y = xp.asarray(grid.centres(0)), xp.asarray(grid.centres(1))
    return GridTerms(
        inside_x=_inside_table_axis(x, problem.half_extents, grid.table, 0, xp),
        inside_y=_inside_table_axis(y, problem.half_extents, grid.table, 1, xp),
        overlap_x=_box_overlap_axis(x, problem, 0, xp) & problem.box_mask[..., None],
        overlap_y=_box_overlap_axis(y, problem, 1, xp),
        x_terms=_tuple_axis_terms(x, geometry, 0, xp),
        y_terms=_tuple_axis_terms(y, geometry, 1, xp),
        radius_sq_min=geometry.radius_sq_min,
        radius_sq_max=geometry.radius_sq_max,
    )


def feasible_cells(problem: PlacementProblem, grid: Grid = DEFAULT_GRID, *, xp=np):
    """`(..., nx, ny)` bool: `check_grid(...).success`, computed from `grid_terms`."""
    terms = grid_terms(problem, grid, xp=xp)
    return _fold(xp, lambda k, mask: mask & terms.tuple_holds(k), terms.fits(xp), terms.radius_sq_min.shape[-1])


def feasible_grid(problem: PlacementProblem, grid: Grid = DEFAULT_GRID) -> np.ndarray:
    """`(..., nx, ny)` bool: the oracle's feasible region, cells whose centre passes the metric."""
    return feasible_cells(problem, grid)


def oracle_placement(feasible: np.ndarray, grid: Grid = DEFAULT_GRID, scene: str = "scene") -> np.ndarray:
    """`(2,)` the feasible cell centre farthest from any infeasible cell or the grid's edge.

    The deepest point leaves the most room for the physical check. Raises NoFeasiblePlacement
    when `feasible (nx, ny)` is empty.
    """
    from scipy import ndimage

    feasible = np.asarray(feasible, dtype=bool)
    if not feasible.any():
        raise NoFeasiblePlacement(scene, "the oracle's feasible region is empty")
    depth = ndimage.distance_transform_edt(np.pad(feasible, 1))[1:-1, 1:-1]
    ix, iy = np.unravel_index(np.argmax(depth), depth.shape)
    return grid.cell_centres()[ix, iy]


def sample_oracle_placements(
    feasible: np.ndarray, num: int, rng: np.random.Generator, grid: Grid = DEFAULT_GRID, scene: str = "scene"
) -> np.ndarray:
    """`(num, 2)` feasible cell centres drawn uniformly (with replacement) from `feasible (nx, ny)`."""
    cells = np.argwhere(np.asarray(feasible, dtype=bool))
    if len(cells) == 0:
        raise NoFeasiblePlacement(scene, "the oracle's feasible region is empty")
    picks = cells[rng.integers(len(cells), size=num)]
    return grid.cell_centres()[picks[:, 0], picks[:, 1]]
