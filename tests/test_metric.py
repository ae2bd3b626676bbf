"""The success metric (docs/design.md#success-metric) and the oracle's feasible-region grid."""

import itertools

import jax.numpy as jnp
import numpy as np
import pytest
import synthetic_problems as synthetic
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from ocplace.errors import InvalidPlacementProblem, NoFeasiblePlacement
from ocplace.sim import metric, relations
from ocplace.sim.metric import FLOAT, GroundedTuple, encode_problem
from ocplace.sim.workspace import DEFAULT_TABLE

# A reference object centred exactly on the origin, so p - c is exact.
CENTRED = np.array([[-0.03125, -0.03125], [0.03125, 0.03125]])
SMALL = (0.0078125, 0.0078125)  # exact half-extents of the held object's footprint


def success(placements, problem):
    return metric.placement_success(np.asarray(placements, dtype=FLOAT).reshape(-1, 2), problem)


def holds(placements, problem):
    """Whether the first tuple holds (the relation alone, whatever the table edge says)."""
    return metric.check_placements(np.asarray(placements, dtype=FLOAT).reshape(-1, 2), problem).tuples[0]


def up(value):
    return np.nextafter(FLOAT(value), FLOAT(np.inf))


def down(value):
    return np.nextafter(FLOAT(value), FLOAT(-np.inf))


@pytest.mark.parametrize("name", relations.RELATION_NAMES)
def test_table_relation_holds_exactly_in_its_closed_cells(name):
    problem = encode_problem([GroundedTuple(name)], np.zeros((0, 2, 2)), (0.0, 0.0))
    mask = relations.cell_table()[relations.relation_index(name)]
    for column, row in itertools.product(range(3), range(3)):
        centre = DEFAULT_TABLE.cell_bounds(column, row).mean(axis=0)
        assert success(centre, problem)[0] == mask[column, row], (name, column, row)
    (x0, y0), (x1, y1) = metric.region_table()[relations.relation_index(name)]
    corners = [(x0, y0), (x1, y1), (x0, y1), (x1, y0)]
    assert success(corners, problem).all(), "region edges are closed"
    outside = [(down(x0), y0), (up(x1), y1), (x0, down(y0)), (x1, up(y1))]
    assert not success(outside, problem).any()


def test_shared_cell_edges_count_for_both_cells():
    (_, _), (left_edge, _) = metric.region_table()[relations.relation_index("left")]
    point = [left_edge, 0.0]
    for name in ("left", "middle"):
        assert success(point, encode_problem([GroundedTuple(name)], [], (0, 0)))[0], name


@pytest.mark.parametrize("name", relations.OBJECT_RELATION_NAMES)
def test_object_relation_distance_bounds_are_inclusive(name):
    problem = encode_problem([GroundedTuple(name, CENTRED)], [CENTRED], SMALL)
    direction = np.asarray(relations.relation(name).direction)
    assert holds(0.2 * direction, problem)[0]
    if np.count_nonzero(direction) == 1:  # exact along an axis
        for radius, inside in ((0.10, True), (0.30, True), (down(0.10), False), (up(0.30), False)):
            assert holds(FLOAT(radius) * direction.astype(FLOAT), problem)[0] == inside, radius
    assert not holds(0.05 * direction, problem)[0]
    assert not holds(0.35 * direction, problem)[0]
    assert not holds(-0.2 * direction, problem)[0]


@pytest.mark.parametrize("name", relations.OBJECT_RELATION_NAMES)
def test_object_relation_cone_is_45_degrees_inclusive(name):
    problem = encode_problem([GroundedTuple(name, CENTRED)], [], SMALL)
    direction = np.asarray(relations.relation(name).direction)
    for sign in (1.0, -1.0):
        angle = sign * np.pi / 4
        rotation = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
        edge = rotation @ direction
        # On the cone's edge the coordinates are equal in magnitude (or one is zero): exact.
        edge = np.where(np.abs(edge) < 1e-9, 0.0, np.sign(edge)) * 0.15
        if np.count_nonzero(edge) == 1:
            edge *= 1.25
        assert holds(edge, problem)[0], (name, edge)
        beyond = rotation @ (rotation @ direction) * 0.2
        assert not holds(beyond, problem)[0]


def test_just_outside_a_cone_fails():
    right = encode_problem([GroundedTuple("right", CENTRED)], [], SMALL)
    assert holds([0.15, 0.15], right)[0] and not holds([0.15, up(0.15)], right)[0]
    back_right = encode_problem([GroundedTuple("back right", CENTRED)], [], SMALL)
    assert holds([0.15, 0.0], back_right)[0] and not holds([0.15, -1e-7], back_right)[0]


def test_touching_boxes_do_not_collide_and_overlaps_do():
    box = np.array([[0.25, -0.125], [0.375, 0.125]])
    problem = encode_problem([GroundedTuple("middle")], [box], (0.0625, 0.0625))
    edges_and_corner = [[0.1875, 0.0], [0.4375, 0.0], [0.3125, 0.1875], [0.3125, -0.1875], [0.1875, 0.1875]]
    assert metric.check_placements(np.asarray(edges_and_corner, FLOAT), problem).collision_free.all()
    overlap = 1e-6  # the smallest overlap the float32 sums p +- h still see is about one ulp
    overlapping = [[0.1875 + overlap, 0.0], [0.3125, 0.1875 - overlap], [0.4375 - overlap, 0.1875 - overlap]]
    assert not metric.check_placements(np.asarray(overlapping, FLOAT), problem).collision_free.any()


def test_footprint_must_lie_inside_the_table_top():
    problem = encode_problem([GroundedTuple("left")], [], (0.0625, 0.03125))
    edge = -0.4 + 0.0625
    assert success([edge, 0.0], problem)[0]
    assert not success([down(edge), 0.0], problem)[0]
    assert not success([edge, 0.3 - 0.03], problem)[0]


def test_padded_tuples_hold_and_padded_boxes_never_collide():
    problem = encode_problem([GroundedTuple("back")], [CENTRED], SMALL, max_tuples=4, max_boxes=6)
    checks = metric.check_placements(np.array([[0.0, 0.2]], FLOAT), problem)
    assert checks.tuples[1:].all() and checks.success.all()
    assert problem.box_mask.tolist() == [True] + [False] * 5


def test_encoding_rejects_impossible_problems():
    with pytest.raises(InvalidPlacementProblem, match="table only"):
        encode_problem([GroundedTuple("middle", CENTRED)], [], SMALL)
    with pytest.raises(InvalidPlacementProblem, match="1 to 4 tuples"):
        encode_problem([GroundedTuple("left")] * 5, [], SMALL)
    with pytest.raises(InvalidPlacementProblem, match="valid AABB"):
        encode_problem([GroundedTuple("left", [[0.1, 0.1], [0.0, 0.2]])], [], SMALL)
    with pytest.raises(InvalidPlacementProblem, match="half-extents"):
        encode_problem([GroundedTuple("left")], [], (-0.01, 0.01))
    with pytest.raises(KeyError, match="canonical relations"):
        encode_problem([GroundedTuple("upwards")], [], SMALL)


def test_split_square_is_close_to_the_square():
    values = np.random.default_rng(0).uniform(-1.0, 1.0, 10_000).astype(FLOAT)
    exact = values.astype(np.float64) ** 2
    assert np.all(np.abs(metric.split_square(values) - exact) <= 2 * np.spacing(exact.astype(FLOAT)))


def _boundary_points(problem, rng, count):
    """Placements on and next to every boundary of the problem: region edges, radii, cones, boxes."""
    geometry = metric.tuple_geometry(problem)
    points = [rng.uniform(-0.45, 0.45, (count, 2))]
    for k in range(problem.relation.shape[-1]):
        centre = geometry.centre[k]
        angles = rng.uniform(0, 2 * np.pi, count)
        for radius in (metric.RADIUS_MIN, metric.RADIUS_MAX):
            points.append(centre + radius * np.stack([np.cos(angles), np.sin(angles)], axis=1))
        offsets = rng.uniform(-0.3, 0.3, count)
        points.append(centre + np.stack([offsets, offsets], axis=1))
        points.append(centre + np.stack([offsets, -offsets], axis=1))
    for box in problem.boxes:
        for corner in (box[0] - problem.half_extents, box[1] + problem.half_extents):
            points.append(np.stack([np.full(count, corner[0]), rng.uniform(-0.3, 0.3, count)], axis=1))
            points.append(np.stack([rng.uniform(-0.4, 0.4, count), np.full(count, corner[1])], axis=1))
    points = np.concatenate(points).astype(FLOAT)
    nudged = [np.nextafter(points, FLOAT(direction)) for direction in (np.inf, -np.inf)]
    return np.concatenate([points, *nudged])


def test_numpy_and_jax_metrics_agree_exactly_on_boundaries():
    problems, _ = synthetic.random_problems(7, 24)
    rng = np.random.default_rng(1)
    for index in range(24):
        problem = metric.scene_problem(problems, index)
        points = _boundary_points(problem, rng, 64)
        numpy_checks = metric.check_placements(points, problem)
        jax_checks = metric.check_placements_jax(points, problem)
        for name, left, right in zip(metric.PlacementChecks._fields, numpy_checks, jax_checks):
            np.testing.assert_array_equal(left, np.asarray(right), err_msg=name)
        assert 0 < numpy_checks.success.sum() < len(points)


# Slow: the default suite's 15 min budget on 2 cores (docs/performance.md, session 12); the metric's hypothesis tests
# stay in it
@pytest.mark.slow
def test_grid_checks_equal_the_metric_at_cell_centres():
    problems, _ = synthetic.random_problems(3, 6)
    centres = metric.DEFAULT_GRID.cell_centres().reshape(-1, 2)
    grid = metric.check_grid(problems)
    points = metric.check_placements(np.broadcast_to(centres, (6,) + centres.shape), problems)
    shape = (6,) + metric.DEFAULT_GRID.shape
    np.testing.assert_array_equal(grid.success, points.success.reshape(shape))
    np.testing.assert_array_equal(grid.tuples, points.tuples.reshape((6, 4) + shape[1:]))
    np.testing.assert_array_equal(metric.feasible_cells(problems), grid.success)
    np.testing.assert_array_equal(np.asarray(metric.feasible_cells(problems, xp=jnp)), grid.success)


def test_oracle_placement_is_the_deepest_feasible_cell():
    problem = encode_problem([GroundedTuple("front left")], [], SMALL)
    feasible = metric.feasible_grid(problem)
    placement = metric.oracle_placement(feasible)
    low = DEFAULT_TABLE.bounds[0] + SMALL  # the region: the cell, less the footprint at the table edge
    high = DEFAULT_TABLE.cell_bounds(0, 0)[1]
    clearance = np.min(np.concatenate([placement - low, high - placement]))
    assert clearance >= np.min(high - low) / 2 - metric.DEFAULT_GRID.resolution
    assert success(placement, problem)[0]
    with pytest.raises(NoFeasiblePlacement, match="scene s1"):
        metric.oracle_placement(np.zeros_like(feasible), scene="s1")


reference_boxes = st.tuples(
    st.floats(-0.3, 0.3), st.floats(-0.2, 0.2), st.floats(0.01, 0.08), st.floats(0.01, 0.08)
).map(lambda v: np.array([[v[0] - v[2], v[1] - v[3]], [v[0] + v[2], v[1] + v[3]]]))


@st.composite
def problems(draw, max_tuples=4):
    boxes = draw(st.lists(reference_boxes, min_size=1, max_size=6))
    tuples = []
    for _ in range(draw(st.integers(1, max_tuples))):
        if draw(st.booleans()):
            tuples.append(GroundedTuple(draw(st.sampled_from(relations.RELATION_NAMES))))
        else:
            box = boxes[draw(st.integers(0, len(boxes) - 1))]
            tuples.append(GroundedTuple(draw(st.sampled_from(relations.OBJECT_RELATION_NAMES)), box))
    half = draw(st.tuples(st.floats(0.0, 0.06), st.floats(0.0, 0.06)))
    return encode_problem(tuples, boxes, half, max_boxes=6)


@settings(max_examples=60, deadline=None)
@given(problems(), st.integers(0, 2**31 - 1))
def test_oracle_placements_always_pass(problem, seed):
    feasible = metric.feasible_grid(problem)
    assume(feasible.any())
    placements = metric.sample_oracle_placements(feasible, 64, np.random.default_rng(seed))
    placements = np.concatenate([placements, metric.oracle_placement(feasible)[None]])
    assert metric.placement_success(placements, problem).all()
    assert np.asarray(metric.placement_success_jax(placements, problem)).all()


@settings(max_examples=100, deadline=None)
@given(problems(), st.floats(0.0, 1.0), st.floats(0.0, 1.0), st.integers(0, 5))
def test_a_footprint_overlapping_a_box_always_fails(problem, u, v, which):
    which = which % int(problem.box_mask.sum())
    low = problem.boxes[which, 0] - problem.half_extents
    high = problem.boxes[which, 1] + problem.half_extents
    placement = (low + (high - low) * np.array([u, v]) * 0.98 + (high - low) * 0.01).astype(FLOAT)
    inside_open = np.all((placement > low) & (placement < high))
    checks = metric.check_placements(placement[None], problem)
    assert inside_open and not checks.collision_free[0] and not checks.success[0]


@settings(max_examples=60, deadline=None)
@given(problems(), st.integers(0, 2**31 - 1))
def test_numpy_and_jax_metrics_agree_on_random_problems(problem, seed):
    points = _boundary_points(problem, np.random.default_rng(seed), 8)
    for left, right in zip(metric.check_placements(points, problem), metric.check_placements_jax(points, problem)):
        np.testing.assert_array_equal(left, np.asarray(right))
