"""The truncated-Gaussian placement density and its exact sampler (paper III-C, Fig. 5), in JAX.

Per tuple a Gaussian (table: centred on the region, sigma a quarter of a 3x3 cell; object:
centred at c + 0.2 m * direction, sigma 0.05 m) truncated to that tuple's region (normalised
there); several tuples: the average of these densities, truncated to where every tuple holds;
then truncated where the held object's footprint leaves the table or overlaps an object.
Everything lives on the oracle's grid (`ocplace.sim.metric.feasible_grid`): the support is the
oracle's feasible region. Sampling is exact: a categorical draw over cells with integer weights,
then uniform jitter inside the cell when the whole cell (plus a small margin) is feasible, else
the cell's centre. See docs/placement.md.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ocplace.serial import bounded
from ocplace.sim import metric, relations
from ocplace.sim.metric import FLOAT, Grid, PlacementProblem, TupleGeometry
from ocplace.vocabulary import MAX_SAMPLES

_TINY = FLOAT(np.finfo(FLOAT).tiny)
_WEIGHT_SCALE = 2**30  # integer weights sum to about 2^30 < 2^31: exact int32 prefix sums
_BLOCK = 8  # cells per block of the hierarchical categorical draw
_SUPER = 16  # blocks per super-block


@dataclasses.dataclass(frozen=True)
class SamplerConfig:
    grid: Grid = Grid()
    num_samples: int = bounded(1024, 1, MAX_SAMPLES)
    table_sigma_cells: float = bounded(0.25, 1e-3, 100.0)  # table tuples: sigma = this x the 3x3 cell size, per axis
    object_offset: float = bounded(0.20, 0.0, 1.0)  # metres from the reference centre along the direction
    object_sigma: float = bounded(0.05, 1e-4, 1.0)  # metres
    jitter_margin: float = bounded(
        1e-5, 0.0, 0.01
    )  # metres; a jittered cell must be feasible this far beyond its edges
    scenes_per_step: int = bounded(16, 1, 1024)  # scenes vmapped together; a step's grids stay in cache


def default_config() -> SamplerConfig:
    return SamplerConfig()


class PlacementResult(NamedTuple):
    samples: Any  # (num_scenes, num_samples, 2) float32; NaN for an empty scene
    heatmap: Any  # (num_scenes, nx, ny) float32 density per m^2; sums to 1 / cell_area; zeros if empty
    mode: Any  # (num_scenes, 2) float32 centre of the most probable cell; NaN if empty
    empty: Any  # (num_scenes,) bool: no cell is feasible


def _table_region_mass(config: SamplerConfig) -> np.ndarray:
    """`(9,)` mass of each table tuple's Gaussian inside its region rectangle (closed form)."""
    regions = metric.region_table(config.grid.table).astype(np.float64)
    sigma = config.table_sigma_cells * config.grid.table.cell_size
    half_widths = (regions[:, 1] - regions[:, 0]) / 2.0  # the Gaussian sits at the region's centre
    return np.prod([[math.erf(w / (s * math.sqrt(2.0))) for w, s in zip(row, sigma)] for row in half_widths], axis=1)


def _object_region_mass(config: SamplerConfig, order: int = 64) -> float:
    """Mass of an object tuple's Gaussian inside its annular sector, by Gauss-Legendre quadrature.

    The same for every direction: the Gaussian is isotropic and the sector turns with it.
    """
    nodes, node_weights = np.polynomial.legendre.leggauss(order)
    low, high = metric.RADIUS_MIN, metric.RADIUS_MAX
    radius = (high - low) / 2.0 * nodes + (high + low) / 2.0
    angle = np.pi / 4.0 * nodes
    r, a = np.meshgrid(radius, angle, indexing="ij")
    sigma = config.object_sigma
    density = np.exp(-0.5 * ((r * np.cos(a) - config.object_offset) ** 2 + (r * np.sin(a)) ** 2) / sigma**2)
    density /= 2.0 * np.pi * sigma**2
    weights = np.outer(node_weights, node_weights) * (high - low) / 2.0 * np.pi / 4.0
    return float(np.sum(weights * density * r))


@functools.cache
def tuple_gaussians(config: SamplerConfig) -> dict[str, np.ndarray]:
    """Per-relation Gaussian parameters, `(9, ...)` for table and for object references.

    `*_scale` turns exp(-z^2/2) into the tuple's truncated density: 1 / (2 pi sx sy Z) with Z the
    Gaussian's mass inside the tuple's region (the whole annular sector for an object: the
    table's edge and the objects truncate later, for all tuples together).
    """
    regions = metric.region_table(config.grid.table).astype(np.float64)
    table_sigma = config.table_sigma_cells * config.grid.table.cell_size
    object_sigma = np.full(2, config.object_sigma)
    return {
        "table_mean": regions.mean(axis=1).astype(FLOAT),
        "table_sigma": np.tile(table_sigma, (9, 1)).astype(FLOAT),
        "table_scale": (1.0 / (2.0 * np.pi * np.prod(table_sigma) * _table_region_mass(config))).astype(FLOAT),
        "object_offset": (config.object_offset * relations.direction_table()).astype(FLOAT),
        "object_sigma": np.tile(object_sigma, (9, 1)).astype(FLOAT),
        "object_scale": np.full(9, 1.0 / (2.0 * np.pi * config.object_sigma**2 * _object_region_mass(config)), FLOAT),
    }


def _gaussians(problem: PlacementProblem, config: SamplerConfig):
    """`(K, 2)` means, `(K, 2)` standard deviations and `(K,)` density scales (0 for padding)."""
    params = {name: jnp.asarray(value)[problem.relation] for name, value in tuple_gaussians(config).items()}
    box = jnp.asarray(problem.reference_box, dtype=FLOAT)
    is_object = jnp.asarray(problem.reference_is_object)
    centre = (box[:, 0] + box[:, 1]) * FLOAT(0.5)
    mean = jnp.where(is_object[:, None], centre + params["object_offset"], params["table_mean"])
    sigma = jnp.where(is_object[:, None], params["object_sigma"], params["table_sigma"])
    scale = jnp.where(is_object, params["object_scale"], params["table_scale"])
    return mean, sigma, jnp.where(problem.tuple_mask, scale, 0.0)


def scene_density(problem: PlacementProblem, config: SamplerConfig, active_tuples=None):
    """One scene's unnormalised weights `(nx, ny)` and feasible cells `(nx, ny)` bool.

    The weight of a feasible cell is the average of the tuples' truncated Gaussian densities at
    its centre. Tuples from `active_tuples` (a traced int, default K) on must be padding: they
    always hold, so the loop skips them.
    """
    grid = config.grid
    terms = metric.grid_terms(problem, grid, xp=jnp)
    mean, sigma, scale = _gaussians(problem, config)
    x, y = jnp.asarray(grid.centres(0)), jnp.asarray(grid.centres(1))
    gauss_x = scale[:, None] * jnp.exp(-0.5 * jnp.square((x - mean[:, :1]) / sigma[:, :1]))  # (K, nx)
    gauss_y = jnp.exp(-0.5 * jnp.square((y - mean[:, 1:]) / sigma[:, 1:]))  # (K, ny)

    # One float array carries both results: 0 marks a cell some constraint rules out, else it
    # holds tiny plus the average of the tuples' densities; tiny keeps a feasible cell drawable
    # where every Gaussian underflows (sigmas far below the defaults) and changes no other weight.
    # A loop over tuples, not unrolled code: see metric._fold.
    gauss_x = gauss_x / problem.tuple_mask.sum()

    def add_tuple(k, weights):
        gauss = gauss_x[k][:, None] * gauss_y[k][None, :]
        return jnp.where(terms.tuple_holds(k) & (weights > 0), weights + gauss, FLOAT(0))

    weights = jnp.where(terms.fits(jnp), _TINY, FLOAT(0))
    active_tuples = gauss_x.shape[0] if active_tuples is None else active_tuples
    weights = jax.lax.fori_loop(0, active_tuples, add_tuple, weights)
    feasible = weights > 0
    return weights, feasible


def _mul_high(a, b):
    """`floor(a * b / 2**32)` for uint32 `a`, `b`, exactly, in 32-bit arithmetic."""
    low, high = np.uint32(0xFFFF), np.uint32(16)
    a_low, a_high, b_low, b_high = a & low, a >> high, b & low, b >> high
    cross_1, cross_2 = a_low * b_high, a_high * b_low
    middle = ((a_low * b_low) >> high) + (cross_1 & low) + (cross_2 & low)
    return a_high * b_high + (cross_1 >> high) + (cross_2 >> high) + (middle >> high)


def _running_sums(rows):
    """Inclusive prefix sums over the short leading axis of `rows (n, m)`, unrolled."""
    sums = [rows[0]]
    for row in rows[1:]:
        sums.append(sums[-1] + row)
    return jnp.stack(sums)


def _search(cumulative, column, target):
    """Branchless binary search in `cumulative (n, G)`, n a power of two, monotone along axis 0.

    Returns `k`, the number of entries of `cumulative[:, column]` at most `target`, and
    `target - cumulative[k - 1, column]` (or `target` when k = 0); `column`, `target` are `(N,)`.
    A loop, not unrolled steps: XLA would otherwise recompute earlier steps inside later ones.
    """

    def step(i, state):
        count, start = state
        half = cumulative.shape[0] >> (i + 1)
        value = cumulative[count + half - 1, column]
        passed = value <= target
        return jnp.where(passed, count + half, count), jnp.where(passed, value, start)

    steps = cumulative.shape[0].bit_length() - 1
    count, start = jax.lax.fori_loop(0, steps, step, (jnp.zeros_like(target), jnp.zeros_like(target)))
    return count, target - start


def sample_cells(bits, weights):
    """`(N,)` flat cell indices drawn with probability proportional to `weights (n,)`.

    `bits (N,)` uint32 are uniform random words. Weights are rounded to integers summing to about
    2^30, every positive weight to at least 1, and the draw is integer arithmetic from there on:
    a cell of weight zero is never drawn, and each cell's probability is its integer weight's
    share to within 2^-32. Cells are grouped in blocks of 8 and blocks in super-blocks of 16
    (strided groups keep the long axis last, which XLA vectorises): a draw is a binary search
    over super-blocks, one over the blocks of its super-block, and a count over 8 cells.
    """
    total = weights.sum()
    quantised = jnp.round(weights * (_WEIGHT_SCALE / jnp.where(total > 0, total, 1.0))).astype(jnp.int32)
    quantised = jnp.where(weights > 0, jnp.maximum(quantised, 1), 0)
    cells = jnp.pad(quantised, (0, -quantised.shape[0] % (_BLOCK * _SUPER))).reshape(_BLOCK, -1)
    # Block b holds cells b + i * num_blocks; super-block s holds blocks s + j * num_super.
    blocks = _running_sums(cells.sum(axis=0).reshape(_SUPER, -1))  # (SUPER, num_super)
    supers = jnp.cumsum(blocks[-1])
    target = _mul_high(bits, supers[-1].astype(jnp.uint32)).astype(jnp.int32)
    padded = 1 << (supers.shape[0] - 1).bit_length()
    supers = jnp.pad(supers, (0, padded - supers.shape[0]), constant_values=jnp.iinfo(jnp.int32).max)
    super_index, target = _search(supers[:, None], jnp.zeros_like(target), target)
    block_index, target = _search(blocks, super_index, target)
    block = block_index * blocks.shape[1] + super_index
    in_block = _running_sums(cells[:, block])  # (BLOCK, N)
    cell_index = jnp.sum(in_block <= target, axis=0, dtype=jnp.int32)
    return cell_index * cells.shape[1] + block


def cells_fully_feasible(low, high, problem: PlacementProblem, geometry: TupleGeometry, table, margin: float):
    """`(N,)` bool: every point of the rectangles `[low - margin, high + margin]` (`(2, N)`) passes.

    Sufficient conditions, exact up to float32 rounding that the margin absorbs: a rectangle lies
    in a box-shaped constraint iff its corners do, in a half-plane iff its minimum there is >= 0,
    in the annulus iff its farthest point is within the outer and its nearest point outside the
    inner radius, and it avoids an open box iff their open intervals are disjoint on some axis.
    Loops over tuples and boxes (not unrolled) keep XLA from recomputing the test per consumer.
    """
    low = low - margin
    high = high + margin
    half = jnp.asarray(problem.half_extents, dtype=FLOAT)
    bounds = table.bounds.astype(FLOAT)
    fits = (low[0] - half[0] >= bounds[0, 0]) & (low[1] - half[1] >= bounds[0, 1])
    fits &= (high[0] + half[0] <= bounds[1, 0]) & (high[1] + half[1] <= bounds[1, 1])

    def add_tuple(ok, tuple_geometry: TupleGeometry):
        to_low = [low[a] - tuple_geometry.centre[a] for a in (0, 1)]
        to_high = [high[a] - tuple_geometry.centre[a] for a in (0, 1)]
        farthest = [jnp.maximum(jnp.abs(to_low[a]), jnp.abs(to_high[a])) for a in (0, 1)]
        nearest = [jnp.maximum(jnp.maximum(to_low[a], -to_high[a]), 0.0) for a in (0, 1)]
        ok &= farthest[0] ** 2 + farthest[1] ** 2 <= tuple_geometry.radius_sq_max
        ok &= nearest[0] ** 2 + nearest[1] ** 2 >= tuple_geometry.radius_sq_min
        for normal in tuple_geometry.normals:
            ok &= sum(jnp.minimum(normal[a] * to_low[a], normal[a] * to_high[a]) for a in (0, 1)) >= 0.0
        for a in (0, 1):
            ok &= (low[a] >= tuple_geometry.rect_low[a]) & (high[a] <= tuple_geometry.rect_high[a])
        return ok, None

    def add_box(ok, box_and_mask):
        box, present = box_and_mask
        overlap = present
        for a in (0, 1):
            overlap &= (low[a] - half[a] < box[1, a]) & (high[a] + half[a] > box[0, a])
        return ok & ~overlap, None

    ok, _ = jax.lax.scan(add_tuple, fits, geometry)
    ok, _ = jax.lax.scan(add_box, ok, (jnp.asarray(problem.boxes, dtype=FLOAT), problem.box_mask))
    return ok


def _first_argmax(weights):
    """Flat index of the first maximum of `weights (nx, ny)`; two small argmaxes beat one big one."""
    column = jnp.argmax(weights.max(axis=1))
    return column * weights.shape[1] + jnp.argmax(weights[column])


def _cell_points(cell, grid: Grid):
    """Lower corners, upper corners and centres `(2, N)` of flat cell indices `(N,)`."""
    index = (cell // grid.shape[1], cell % grid.shape[1])
    low = jnp.stack([jnp.asarray(grid.edges(a))[index[a]] for a in (0, 1)])
    high = jnp.stack([jnp.asarray(grid.edges(a))[index[a] + 1] for a in (0, 1)])
    centre = jnp.stack([jnp.asarray(grid.centres(a))[index[a]] for a in (0, 1)])
    return low, high, centre


def _sample_scene(key, problem: PlacementProblem, config: SamplerConfig, active_tuples=None) -> PlacementResult:
    grid = config.grid
    weights, _ = scene_density(problem, config, active_tuples)
    empty = ~(weights.max() > 0)  # weights are positive exactly on feasible cells
    heatmap = weights * jnp.where(empty, 0.0, 1.0 / (weights.sum() * grid.cell_area))
    nan = jnp.full((2, 1), jnp.nan, FLOAT)
    mode = jnp.where(empty, nan, _cell_points(_first_argmax(weights)[None], grid)[2])[:, 0]

    bits = jax.random.bits(key, (2, config.num_samples), jnp.uint32)
    low, high, centre = _cell_points(sample_cells(bits[0], weights.reshape(-1)), grid)
    geometry = metric.tuple_geometry(problem, grid.table, xp=jnp)
    whole = cells_fully_feasible(low, high, problem, geometry, grid.table, config.jitter_margin)
    # 16 random bits per axis: the jitter lands on a lattice of 65536 points per cell side.
    halves = jnp.stack([bits[1] & np.uint32(0xFFFF), bits[1] >> np.uint32(16)])
    jitter = (halves.astype(FLOAT) + 0.5) * FLOAT(2.0**-16)
    samples = jnp.where(empty, nan, jnp.where(whole, low + jitter * (high - low), centre))
    return PlacementResult(samples.T, heatmap, mode, empty)


@functools.partial(jax.jit, static_argnames="config")
def sample_placements(key, problems: PlacementProblem, config: SamplerConfig = SamplerConfig()) -> PlacementResult:
    """Samples, heatmap, mode and empty flag for a batch of scenes (leading axis of `problems`).

    Scenes go through in steps of `config.scenes_per_step`, vmapped within a step: with all 256
    scenes at once, every pass over the grids would stream 20 MB through memory.
    """
    problems = metric.as_arrays(problems, jnp)
    keys = jax.random.split(key, problems.relation.shape[0])
    positions = jnp.arange(1, problems.relation.shape[-1] + 1)
    active_tuples = jnp.max(jnp.where(problems.tuple_mask, positions, 0))  # padding K beyond this costs nothing
    return jax.lax.map(
        lambda args: _sample_scene(args[0], args[1], config, active_tuples),
        (keys, problems),
        batch_size=config.scenes_per_step,
    )
