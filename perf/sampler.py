"""Benchmark: the JAX placement sampler against a straightforward NumPy/SciPy reference.

    python perf/sampler.py [--scenes 256] [--samples 1024] [--max-tuples 4] [--repeats 20]

Both run on the same synthetic scenes (5 boxes over the drop area, levels 9:9:22). The reference
draws, per scene, from each tuple's Gaussian with `scipy.stats.truncnorm` (truncated to the
tuple's region rectangle, or the table for an object relation) and rejects draws that fail the
success metric, until it has enough. JAX time is measured after compilation, which is reported
separately. Timings on a shared machine are indicative only.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np


def sector_box(direction: np.ndarray) -> np.ndarray:
    """`(2, 2)` bounding box of an object relation's annular sector around the origin."""
    from ocplace.sim import metric

    heading = np.arctan2(direction[1], direction[0])
    angles = heading + np.linspace(-np.pi / 4, np.pi / 4, 721)
    radii = np.array([metric.RADIUS_MIN, metric.RADIUS_MAX])
    points = radii[:, None, None] * np.stack([np.cos(angles), np.sin(angles)], axis=-1)[None]
    return np.stack([points.reshape(-1, 2).min(axis=0), points.reshape(-1, 2).max(axis=0)])


def reference_samples(problem, num_samples: int, rng: np.random.Generator, config, max_rounds: int = 50):
    """`(num_samples, 2)` placements for one scene by truncnorm proposals and rejection.

    Each tuple proposes from its Gaussian truncated (per axis) to its region's bounding box on the
    table; a tuple is picked uniformly per draw. Returns None when `max_rounds` rounds of
    `2 * num_samples` draws do not accept enough (a small feasible region).
    """
    from scipy import stats

    from ocplace.models.placement import sampler
    from ocplace.sim import metric, relations

    params = sampler.tuple_gaussians(config)
    table = config.grid.table.bounds
    components = []
    for k in np.flatnonzero(problem.tuple_mask):
        relation = problem.relation[k]
        if problem.reference_is_object[k]:
            centre = problem.reference_box[k].mean(axis=0)
            mean, sigma = centre + params["object_offset"][relation], params["object_sigma"][relation]
            low, high = centre + sector_box(relations.direction_table()[relation])
            low, high = np.maximum(low, table[0]), np.minimum(high, table[1])
        else:
            mean, sigma = params["table_mean"][relation], params["table_sigma"][relation]
            low, high = metric.region_table(config.grid.table)[relation]
        components.append((mean.astype(float), sigma.astype(float), low, high))
    accepted = []
    for _ in range(max_rounds):
        batch = 2 * num_samples
        which = rng.integers(len(components), size=batch)
        draws = np.empty((batch, 2))
        for index, (mean, sigma, low, high) in enumerate(components):
            chosen = which == index
            for axis in (0, 1):
                a, b = (low[axis] - mean[axis]) / sigma[axis], (high[axis] - mean[axis]) / sigma[axis]
                draws[chosen, axis] = stats.truncnorm.rvs(
                    a, b, loc=mean[axis], scale=sigma[axis], size=chosen.sum(), random_state=rng
                )
        accepted.append(draws[metric.placement_success(draws, problem)])
        if sum(len(a) for a in accepted) >= num_samples:
            return np.concatenate(accepted)[:num_samples]
    return None


def time_jax(problems, config, repeats: int):
    import jax

    from ocplace.models.placement import sampler

    key = jax.random.key(0)
    start = time.perf_counter()
    compiled = jax.jit(sampler.sample_placements, static_argnames="config").lower(key, problems, config).compile()
    compile_s = time.perf_counter() - start
    jax.block_until_ready(compiled(key, problems))
    times = []
    for repeat in range(repeats):
        start = time.perf_counter()
        result = jax.block_until_ready(compiled(jax.random.key(repeat), problems))
        times.append(time.perf_counter() - start)
    return compile_s, times, jax.device_get(result)


def time_reference(problems, config, num_scenes: int):
    """Seconds per scene and samples, for the scenes where rejection sampling finished."""
    from ocplace.sim import metric

    rng = np.random.default_rng(0)
    seconds, samples, finished = [], [], []
    for index in range(num_scenes):
        start = time.perf_counter()
        drawn = reference_samples(metric.scene_problem(problems, index), config.num_samples, rng, config)
        if drawn is not None:
            seconds.append(time.perf_counter() - start)
            samples.append(drawn)
            finished.append(index)
    return np.asarray(seconds), np.stack(samples), np.asarray(finished)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=256)
    parser.add_argument("--samples", type=int, default=1024)
    parser.add_argument("--max-tuples", type=int, default=4, help="tuple padding K (the paper needs 2)")
    parser.add_argument("--repeats", type=int, default=20)
    args = parser.parse_args()

    import dataclasses

    import jax

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))  # the test support: synthetic inputs
    import synthetic_problems as synthetic

    from ocplace.models.placement import sampler
    from ocplace.sim import metric

    config = dataclasses.replace(sampler.default_config(), num_samples=args.samples)
    problems, levels = synthetic.random_problems(0, args.scenes, max_tuples=args.max_tuples)
    compile_s, times, result = time_jax(problems, config, args.repeats)
    seconds, reference, finished = time_reference(problems, config, args.scenes)
    reference_s = seconds.mean() * args.scenes  # the finished scenes' mean, for all scenes

    jax_median, jax_best = statistics.median(times), min(times)
    passed = metric.placement_success(result.samples, problems).mean()
    reference_passed = metric.placement_success(
        reference, metric.PlacementProblem(*(np.asarray(field)[finished] for field in problems))
    ).mean()
    cores = len(os.sched_getaffinity(0))
    print(
        f"machine: {platform.processor() or platform.machine()}, {cores} cores, jax {jax.__version__} "
        f"({jax.default_backend()}), load average {os.getloadavg()[0]:.2f}"
    )
    print(
        f"scenes {args.scenes} (table {levels.count('table')}, 1obj {levels.count('1obj')}, "
        f"2obj {levels.count('2obj')}), samples per scene {args.samples}, tuple padding K={args.max_tuples}, "
        f"grid {config.grid.shape[0]}x{config.grid.shape[1]} ({config.grid.resolution * 1000:g} mm)"
    )
    print(f"jax compile:          {compile_s:8.2f} s")
    print(
        f"jax sample (median):  {jax_median * 1000:8.1f} ms   best {jax_best * 1000:.1f} ms   over {args.repeats} runs"
    )
    print(
        f"reference (scipy):    {reference_s * 1000:8.1f} ms   ({seconds.mean() * 1000:.2f} ms per scene over the "
        f"{len(finished)} scenes it finished; {args.scenes - len(finished)} gave up after 50 rounds)"
    )
    print(f"throughput ratio:     {reference_s / jax_median:8.1f}x (median)   {reference_s / jax_best:.1f}x (best)")
    print(f"samples passing the metric: jax {passed:.4%}, reference {reference_passed:.4%}")


if __name__ == "__main__":
    main()
