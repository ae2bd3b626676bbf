"""Random placement problems shaped like benchmark scenes, for tests, benchmarks and demos.

Boxes stand in for the AABBs of 5 objects dropped over the table's central area; tuples follow
the benchmark's levels (`table`, `1obj`, `2obj`, in the paper's 9:9:22 ratio).
"""

from __future__ import annotations

import numpy as np

from ocplace.sim import metric, relations
from ocplace.sim.metric import Grid, GroundedTuple, PlacementProblem
from ocplace.sim.workspace import DEFAULT_TABLE
from ocplace.vocabulary import LEVELS, MAX_PARSED_TUPLES

LEVEL_WEIGHTS = (9, 9, 22)


def random_boxes(rng: np.random.Generator, num_boxes: int = 5) -> np.ndarray:
    """`(num_boxes, 2, 2)` AABBs centred over the table's drop area, 4 to 14 cm wide."""
    centres = rng.uniform(-1.0, 1.0, (num_boxes, 2)) * DEFAULT_TABLE.drop_half_extents
    half_sizes = rng.uniform(0.02, 0.07, (num_boxes, 2))
    return np.stack([centres - half_sizes, centres + half_sizes], axis=1)


def random_tuples(rng: np.random.Generator, level: str, boxes: np.ndarray) -> list[GroundedTuple]:
    """The grounded tuples of one instruction of `level` whose references are among `boxes`."""
    if level == "table":
        return [GroundedTuple(str(rng.choice(relations.RELATION_NAMES)))]
    count = {"1obj": 1, "2obj": 2}[level]
    references = rng.choice(len(boxes), size=count, replace=False)
    return [GroundedTuple(str(rng.choice(relations.OBJECT_RELATION_NAMES)), boxes[index]) for index in references]


def random_problem(
    rng: np.random.Generator, level: str, *, max_tuples: int = MAX_PARSED_TUPLES, max_boxes: int = 8
) -> PlacementProblem:
    boxes = random_boxes(rng)
    half_extents = rng.uniform(0.015, 0.05, 2)
    return metric.encode_problem(
        random_tuples(rng, level, boxes), boxes, half_extents, max_tuples=max_tuples, max_boxes=max_boxes
    )


def random_problems(
    seed: int, num_scenes: int, *, grid: Grid = metric.DEFAULT_GRID, max_tuples: int = MAX_PARSED_TUPLES
) -> tuple[PlacementProblem, list[str]]:
    """`num_scenes` solvable problems stacked on a leading axis, and the level of each.

    Levels are drawn 9:9:22; like the benchmark, a problem whose oracle region on `grid` is empty
    is drawn again at the same level.
    """
    rng = np.random.default_rng(seed)
    weights = np.asarray(LEVEL_WEIGHTS) / sum(LEVEL_WEIGHTS)
    levels = [str(level) for level in rng.choice(LEVELS, size=num_scenes, p=weights)]
    problems = []
    for level in levels:
        problem = random_problem(rng, level, max_tuples=max_tuples)
        while not metric.feasible_grid(problem, grid).any():
            problem = random_problem(rng, level, max_tuples=max_tuples)
        problems.append(problem)
    return metric.stack_problems(problems), levels
