"""The truncated-Gaussian placement sampler (docs/placement.md): density, exact sampling, errors, figures."""

import math

import jax
import numpy as np
import pytest
import synthetic_problems as synthetic
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import integrate, stats

from ocplace.errors import NoFeasiblePlacement
from ocplace.models.placement import explain_empty, figures, place, sampler
from ocplace.sim import metric, relations
from ocplace.sim.metric import FLOAT, GroundedTuple
from ocplace.sim.workspace import DEFAULT_TABLE

CONFIG = sampler.default_config()
GRID = CONFIG.grid
BATCH = 8  # every call pads to this many scenes of 4 tuples and 8 boxes: one compilation
BOX_A = np.array([[-0.20, -0.05], [-0.12, 0.03]])
BOX_B = np.array([[0.10, 0.02], [0.16, 0.09]])
HALF = (0.02, 0.015)


def encode(tuples, boxes=(BOX_A, BOX_B), half=HALF):
    return metric.encode_problem(tuples, np.asarray(boxes).reshape(-1, 2, 2), half, max_boxes=8)


def run(problems, seed=0):
    """The sampler on up to BATCH problems, padded with the first; results as NumPy."""
    problems = list(problems)
    stacked = metric.stack_problems(problems + [problems[0]] * (BATCH - len(problems)))
    result = jax.device_get(sampler.sample_placements(jax.random.key(seed), stacked, CONFIG))
    return sampler.PlacementResult(*(np.asarray(field)[: len(problems)] for field in result)), stacked


@pytest.fixture(scope="module")
def synthetic_run():
    problems, _ = synthetic.random_problems(11, BATCH)
    result = jax.device_get(sampler.sample_placements(jax.random.key(5), problems, CONFIG))
    return problems, result


def test_shapes_and_dtypes(synthetic_run):
    _, result = synthetic_run
    nx, ny = GRID.shape
    assert (nx, ny) == (160, 120)
    assert result.samples.shape == (BATCH, CONFIG.num_samples, 2) and result.samples.dtype == np.float32
    assert result.heatmap.shape == (BATCH, nx, ny) and result.heatmap.dtype == np.float32
    assert result.mode.shape == (BATCH, 2) and result.mode.dtype == np.float32
    assert result.empty.shape == (BATCH,) and result.empty.dtype == bool


def test_density_integrates_to_one_with_the_oracle_region_as_support(synthetic_run):
    problems, result = synthetic_run
    np.testing.assert_allclose(result.heatmap.sum(axis=(1, 2)) * GRID.cell_area, 1.0, rtol=1e-5)
    np.testing.assert_array_equal(result.heatmap > 0, metric.feasible_grid(problems, GRID))
    assert not result.empty.any()


def test_no_mass_outside_the_regions_or_inside_inflated_boxes(synthetic_run):
    problems, result = synthetic_run
    centres = GRID.cell_centres()
    for index in range(BATCH):
        problem = metric.scene_problem(problems, index)
        checks = metric.check_grid(problem, GRID)
        assert not result.heatmap[index][~checks.tuples.all(axis=0)].any()
        for box, present in zip(problem.boxes, problem.box_mask):
            if present:
                inside = np.all(
                    (centres > box[0] - problem.half_extents) & (centres < box[1] + problem.half_extents), axis=-1
                )
                assert inside.any() and not result.heatmap[index][inside].any()


def _truncated_density(grounded: GroundedTuple, points: np.ndarray) -> np.ndarray:
    """A tuple's Gaussian normalised over its region (scipy, independent of the sampler)."""
    if grounded.reference_box is None:
        (x0, y0), (x1, y1) = metric.region_table()[relations.relation_index(grounded.relation)].astype(float)
        mean = np.array([(x0 + x1) / 2, (y0 + y1) / 2])
        sigma = CONFIG.table_sigma_cells * DEFAULT_TABLE.cell_size
        half_widths = [(x1 - x0) / 2, (y1 - y0) / 2]
        mass = np.prod([stats.norm.cdf(h, 0, s) - stats.norm.cdf(-h, 0, s) for h, s in zip(half_widths, sigma)])
    else:
        direction = np.asarray(relations.relation(grounded.relation).direction)
        mean = np.asarray(grounded.reference_box, dtype=float).mean(axis=0) + CONFIG.object_offset * direction
        sigma = np.full(2, CONFIG.object_sigma)
        offset, s = CONFIG.object_offset, CONFIG.object_sigma

        def polar(angle, radius):
            return radius * stats.multivariate_normal.pdf(
                [radius * math.cos(angle) - offset, radius * math.sin(angle)], cov=s**2 * np.eye(2)
            )

        mass, _ = integrate.dblquad(polar, metric.RADIUS_MIN, metric.RADIUS_MAX, -math.pi / 4, math.pi / 4)
    return stats.multivariate_normal.pdf(points, mean=mean, cov=np.diag(sigma**2)) / mass


@pytest.mark.parametrize(
    "tuples",
    [
        [GroundedTuple("right", BOX_A), GroundedTuple("back", BOX_B)],
        [GroundedTuple("front right", BOX_A), GroundedTuple("front", None), GroundedTuple("left", BOX_B)],
        [GroundedTuple("back left", None)],
    ],
)
def test_composition_is_the_renormalised_average_of_single_tuple_densities(tuples):
    result, _ = run([encode(tuples)] + [encode([t]) for t in tuples])
    centres = GRID.cell_centres().reshape(-1, 2).astype(float)
    singles = np.stack([_truncated_density(t, centres).reshape(GRID.shape) for t in tuples])
    feasible = metric.feasible_grid(encode(tuples), GRID)
    assert feasible.sum() > 100
    expected = np.where(feasible, singles.mean(axis=0), 0.0)
    expected /= expected.sum() * GRID.cell_area
    np.testing.assert_allclose(result.heatmap[0], expected, rtol=2e-4, atol=1e-6 * expected.max())
    for k, single in enumerate(singles):  # each tuple alone: its density, restricted and renormalised
        alone = np.where(metric.feasible_grid(encode([tuples[k]]), GRID), single, 0.0)
        np.testing.assert_allclose(
            result.heatmap[k + 1], alone / (alone.sum() * GRID.cell_area), rtol=2e-4, atol=1e-6 * alone.max()
        )


def test_same_key_same_result_and_another_key_other_samples():
    problems = [encode([GroundedTuple("left", BOX_B)])]
    first, _ = run(problems, seed=3)
    again, _ = run(problems, seed=3)
    other, _ = run(problems, seed=4)
    for a, b in zip(first, again):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(first.heatmap, other.heatmap)
    assert not np.array_equal(first.samples, other.samples)


def test_padded_tuples_change_nothing():
    two = encode([GroundedTuple("left", BOX_B), GroundedTuple("front", BOX_A)])
    four = encode(
        [
            GroundedTuple("left", BOX_B),
            GroundedTuple("front", BOX_A),
            GroundedTuple("left"),
            GroundedTuple("back right", BOX_A),
        ]
    )
    alone, _ = run([two, two], seed=9)  # the loop stops after 2 tuples
    mixed, _ = run([two, four], seed=9)  # the loop runs 4 tuples; the first scene pads 2
    for a, b in zip(alone, mixed):
        np.testing.assert_array_equal(a[0], b[0])


def test_mode_is_the_centre_of_the_heaviest_cell(synthetic_run):
    _, result = synthetic_run
    for heatmap, mode in zip(result.heatmap, result.mode):
        ix, iy = np.unravel_index(np.argmax(heatmap), heatmap.shape)
        np.testing.assert_array_equal(mode, GRID.cell_centres()[ix, iy])


def test_samples_follow_the_density_and_jitter_inside_cells():
    problem = encode([GroundedTuple("front left", BOX_B), GroundedTuple("back right", BOX_A)])
    draws = [run([problem] * BATCH, seed=seed)[0] for seed in range(2)]
    samples = np.concatenate([d.samples.reshape(-1, 2) for d in draws])
    heatmap = draws[0].heatmap[0]
    ix = np.clip(np.floor((samples[:, 0] - GRID.edges(0)[0]) / GRID.resolution).astype(int), 0, GRID.shape[0] - 1)
    iy = np.clip(np.floor((samples[:, 1] - GRID.edges(1)[0]) / GRID.resolution).astype(int), 0, GRID.shape[1] - 1)
    block = 4  # compare on 2 cm blocks so every block expects many samples
    counts = np.zeros((GRID.shape[0] // block, GRID.shape[1] // block))
    np.add.at(counts, (ix // block, iy // block), 1)
    expected = heatmap.reshape(counts.shape[0], block, counts.shape[1], block).sum(axis=(1, 3))
    expected *= GRID.cell_area * len(samples)
    used = expected > 5
    assert counts[~used].sum() <= 0.01 * len(samples)
    chi_square = np.sum((counts[used] - expected[used]) ** 2 / expected[used])
    assert stats.chi2.sf(chi_square, used.sum() - 1) > 1e-4, chi_square
    centres = GRID.cell_centres()[ix, iy]
    assert np.all(np.abs(samples - centres) <= GRID.resolution / 2 + 1e-7), "samples stay in their cell"
    roomy, _ = run([encode([GroundedTuple("front")], boxes=[])])
    on_centre = (roomy.samples[0][:, None, :] == GRID.cell_centres().reshape(1, -1, 2)).all(axis=-1).any(axis=1)
    assert on_centre.mean() < 0.02, "away from the region's edge, samples are jittered inside their cell"


def test_sample_cells_matches_probabilities_and_never_draws_zero_weight():
    rng = np.random.default_rng(0)
    weights = rng.uniform(0, 1, 19200).astype(FLOAT) * (rng.uniform(0, 1, 19200) < 0.05)
    weights[:100] = 0.0
    weights[100] = 50.0
    bits = jax.random.bits(jax.random.key(0), (1 << 18,), np.uint32)
    cells = np.asarray(jax.jit(sampler.sample_cells)(bits, weights))
    counts = np.bincount(cells, minlength=len(weights))
    assert counts[weights == 0].sum() == 0
    expected = weights / weights.sum() * len(cells)
    heavy = expected > 20
    chi_square = np.sum((counts[heavy] - expected[heavy]) ** 2 / expected[heavy])
    assert stats.chi2.sf(chi_square, heavy.sum() - 1) > 1e-4
    assert abs(counts[100] - expected[100]) < 5 * math.sqrt(expected[100])


def test_mul_high_is_exact():
    a, b = np.random.default_rng(1).integers(0, 2**32, (2, 10_000), dtype=np.uint64)
    high = np.asarray(jax.jit(sampler._mul_high)(a.astype(np.uint32), b.astype(np.uint32)))
    assert [int(h) for h in high] == [(int(x) * int(y)) >> 32 for x, y in zip(a, b)]


def test_region_masses_match_numerical_integration():
    object_mass = sampler._object_region_mass(CONFIG)
    reference = float(_truncated_density(GroundedTuple("right", [[0, 0], [0, 0]]), np.array([[0.2, 0.0]])))
    peak = stats.multivariate_normal.pdf([0, 0], cov=CONFIG.object_sigma**2 * np.eye(2))
    assert math.isclose(peak / object_mass, reference, rel_tol=1e-6)
    table_mass = sampler._table_region_mass(CONFIG)
    assert math.isclose(table_mass[relations.relation_index("middle")], math.erf(2 / math.sqrt(2)) ** 2, rel_tol=1e-6)


def test_an_empty_region_is_flagged_by_the_core_and_an_error_from_place():
    disjoint = encode([GroundedTuple("back"), GroundedTuple("front")])
    too_big = encode([GroundedTuple("middle")], half=(0.45, 0.01))
    blocked = encode([GroundedTuple("middle")], boxes=[[[-0.2, -0.15], [0.2, 0.15]]])
    solvable = encode([GroundedTuple("left")])
    result, _ = run([disjoint, too_big, blocked, solvable])
    assert result.empty.tolist() == [True, True, True, False]
    assert np.isnan(result.samples[:3]).all() and np.isnan(result.mode[:3]).all()
    assert not result.heatmap[:3].any()
    expected = r"scene kitchen-7: tuple 1 \('front' part of the table\) does not intersect"
    with pytest.raises(NoFeasiblePlacement, match=expected):
        place(jax.random.key(0), disjoint, CONFIG, scene_names=["kitchen-7"])
    assert "does not fit on the table" in explain_empty(too_big, GRID)
    assert "collides with scene object 0" in explain_empty(blocked, GRID)
    far = encode([GroundedTuple("left", [[-0.39, 0.0], [-0.38, 0.01]])])
    assert "has no cell on the table" in explain_empty(far, GRID)
    batch = metric.stack_problems([solvable, blocked] + [solvable] * (BATCH - 2))
    with pytest.raises(NoFeasiblePlacement, match="scene #1: the held object's footprint"):
        place(jax.random.key(0), batch, CONFIG)
    single = place(jax.random.key(0), solvable, CONFIG)
    assert single.samples.shape == (CONFIG.num_samples, 2)


def _coordinate(low, high):
    """Floats that often sit on or next to the 5 mm grid's edges and centres."""
    lattice = st.integers(int(low / 0.0025), int(high / 0.0025)).map(lambda k: k * 0.0025)
    nudged = st.tuples(lattice, st.sampled_from([-1e-6, -1e-7, 1e-7, 1e-6])).map(sum)
    return st.one_of(st.floats(low, high), lattice, nudged)


@st.composite
def scenes(draw):
    boxes = []
    for _ in range(draw(st.integers(1, 8))):
        x0, y0 = draw(_coordinate(-0.35, 0.3)), draw(_coordinate(-0.25, 0.2))
        w, h = draw(_coordinate(0.005, 0.12)), draw(_coordinate(0.005, 0.12))
        boxes.append([[x0, y0], [x0 + abs(w), y0 + abs(h)]])
    tuples = []
    for _ in range(draw(st.integers(1, 4))):
        if draw(st.integers(0, 3)) == 0:
            tuples.append(GroundedTuple(draw(st.sampled_from(relations.RELATION_NAMES))))
        else:
            box = boxes[draw(st.integers(0, len(boxes) - 1))]
            tuples.append(GroundedTuple(draw(st.sampled_from(relations.OBJECT_RELATION_NAMES)), box))
    half = (abs(draw(_coordinate(0.0, 0.06))), abs(draw(_coordinate(0.0, 0.06))))
    return encode(tuples, boxes, half)


@settings(max_examples=25, deadline=None)
@given(st.lists(scenes(), min_size=BATCH, max_size=BATCH), st.integers(0, 2**31 - 1))
def test_every_sample_and_the_mode_pass_the_metric(problems, seed):
    result, stacked = run(problems, seed)
    feasible = metric.feasible_grid(stacked, GRID)
    np.testing.assert_array_equal(result.empty, ~feasible.any(axis=(1, 2)))
    for index in np.flatnonzero(~result.empty):
        problem = metric.scene_problem(stacked, index)
        placements = np.concatenate([result.samples[index], result.mode[index][None]])
        assert metric.placement_success(placements, problem).all()
        assert np.asarray(metric.placement_success_jax(placements, problem)).all()


def _orthographic(points):
    """Table plane to a 200 x 150 image: 250 px per metre, image up = +y."""
    points = np.asarray(points, dtype=float)
    return np.stack([(points[:, 0] + 0.4) * 250 - 0.5, (0.3 - points[:, 1]) * 250 - 0.5], axis=1)


def test_fig5_panels_draw_on_any_image(tmp_path):
    image = np.zeros((150, 200, 3), np.uint8)
    image[..., 1] = 90
    boxes = np.stack([BOX_A, BOX_B])
    figure = figures.fig5(
        jax.random.key(0),
        image,
        _orthographic,
        boxes,
        HALF,
        rng=np.random.default_rng(0),
        names=["mug", "shoe"],
        config=CONFIG,
    )
    path = figures.save_figure(figure, tmp_path / "fig5.png")
    from PIL import Image

    drawn = np.asarray(Image.open(path).convert("RGB")).astype(int)
    assert drawn.shape[0] > 200 and drawn.shape[1] > 3 * drawn.shape[0] / 2
    background = (drawn[..., 0] < 30) & (np.abs(drawn[..., 1] - 90) < 15) & (drawn[..., 2] < 30)
    coloured = (drawn[..., 0] > 80) & ~(drawn > 240).all(axis=-1)  # densities, samples: not the green image
    assert background.mean() > 0.3 and coloured.mean() > 0.01

    class Camera:  # anything with world_to_pixel works too
        world_to_pixel = staticmethod(_orthographic)

    chosen = figures.choose_fig5_tuples(np.random.default_rng(0), boxes, HALF, ["mug", "shoe"], GRID)
    assert [len(t) for _, t, _ in chosen] == [1, 1, 2]
    assert chosen[0][1][0].reference_box is None and "mug" in chosen[1][0] + chosen[2][0]
    panels = [figures.Panel(t, np.ones(GRID.shape), np.zeros((3, 2)), np.zeros(2), refs) for t, _, refs in chosen]
    figures.save_figure(figures.draw_panels(image, Camera(), panels, GRID), tmp_path / "camera.png")
    assert (tmp_path / "camera.png").stat().st_size > 1000


def _densities_parser():
    import argparse

    from ocplace.cli import densities

    parser = argparse.ArgumentParser()
    densities.register(parser.add_subparsers(dest="command"))
    return parser


def test_densities_command_is_registered():
    args = _densities_parser().parse_args(["densities", "--seed", "3", "--out", "x.png"])
    assert (args.seed, args.split, str(args.out)) == (3, "seen", "x.png")


@pytest.mark.slow
def test_densities_draws_fig5_on_a_real_scene(tmp_path, library):
    from PIL import Image

    out = tmp_path / "fig5.png"
    args = _densities_parser().parse_args(["densities", "--seed", "1", "--out", str(out)])
    assert args.func(args) == 0
    assert Image.open(out).size[0] > 1000
