"""The public placement call: the batched sampler plus a typed error for an empty region."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ocplace.errors import NoFeasiblePlacement
from ocplace.models.placement.sampler import PlacementResult, SamplerConfig, sample_placements
from ocplace.sim import metric, relations
from ocplace.sim.metric import Grid, PlacementProblem


def _describe_tuple(problem: PlacementProblem, k: int) -> str:
    relation = relations.RELATION_NAMES[int(problem.relation[k])]
    if not problem.reference_is_object[k]:
        return f"tuple {k} ({relation!r} part of the table)"
    (x0, y0), (x1, y1) = np.asarray(problem.reference_box[k], dtype=float)
    return f"tuple {k} ({relation!r} of the object at [{x0:.3f}, {y0:.3f}]-[{x1:.3f}, {y1:.3f}] m)"


def explain_empty(problem: PlacementProblem, grid: Grid = metric.DEFAULT_GRID) -> str:
    """Which constraint empties one scene's feasible region, adding them in order.

    Order: each tuple, then the footprint inside the table, then each scene object's box. Returns
    a sentence naming the first constraint after which no cell of `grid` is left.
    """
    problem = metric.as_arrays(problem)
    checks = metric.check_grid(problem, grid)
    terms = metric.grid_terms(problem, grid)
    region = np.ones(grid.shape, bool)
    named: list[str] = []
    for k in (int(k) for k in np.flatnonzero(problem.tuple_mask)):
        region &= checks.tuples[k]
        if not region.any():
            if not named:
                return f"the region of {_describe_tuple(problem, k)} has no cell on the table"
            return f"{_describe_tuple(problem, k)} does not intersect the region of {', '.join(named)}"
        named.append(_describe_tuple(problem, k))
    where = f"the region of {', '.join(named)}" if named else "the table"
    hx, hy = (2.0 * np.asarray(problem.half_extents, dtype=float)).tolist()
    region &= checks.inside_table
    if not region.any():
        return f"the held object's footprint ({hx:.3f} x {hy:.3f} m) does not fit on the table within {where}"
    for b in np.flatnonzero(problem.box_mask):
        region &= terms.box_clear(b)
        if not region.any():
            (x0, y0), (x1, y1) = np.asarray(problem.boxes[b], dtype=float)
            return (
                f"the held object's footprint ({hx:.3f} x {hy:.3f} m) collides with scene object {b} "
                f"(box [{x0:.3f}, {y0:.3f}]-[{x1:.3f}, {y1:.3f}] m) wherever it would satisfy {where}"
                + (" and avoid the objects before it" if b > 0 else "")
            )
    return "no cell passes the metric"


def place(
    key,
    problems: PlacementProblem,
    config: SamplerConfig = SamplerConfig(),
    scene_names: Sequence[str] | None = None,
) -> PlacementResult:
    """Samples placements for one scene (fields without a scene axis) or a batch of scenes.

    Raises NoFeasiblePlacement naming the first scene whose feasible region is empty and the
    constraint that emptied it; `sample_placements` is the batched core that flags it instead.
    """
    single = np.ndim(problems.relation) == 1
    batch = metric.stack_problems([problems]) if single else problems
    result = sample_placements(key, batch, config)
    empty = np.asarray(result.empty)
    if empty.any():
        index = int(np.flatnonzero(empty)[0])
        name = scene_names[index] if scene_names is not None else f"#{index}"
        raise NoFeasiblePlacement(name, explain_empty(metric.scene_problem(batch, index), config.grid))
    if single:
        return PlacementResult(*(field[0] for field in result))
    return result
