"""Benchmark: CLIPort-Place's pixel sampler, inverse CDF (shipped) against Gumbel-max (before issue 42).

    python perf/cliport_sampler.py [--scenes 16] [--samples 1024] [--repeats 5]

Per scene, both draw `--samples` pixels from one `(h * w,)` distribution at the default resolution
(160 x 120): maps with the spread of a trained network's (89-90% of the pixels within 10 nats of the
best, docs/performance.md), jitted, timed after compilation, the median over `--repeats` passes over
the scenes. Prints milliseconds per scene for each and the ratio.
"""

from __future__ import annotations

import argparse
import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np

from ocplace.methods.cliport import model as cliport
from ocplace.methods.cliport.recipe import CliportConfig


def _maps(scenes: int, config: CliportConfig) -> list[jax.Array]:
    rng = np.random.default_rng(0)
    logits = rng.normal(0.0, 2.0, (scenes, config.num_pixels))
    weights = np.exp(logits - logits.max(axis=1, keepdims=True))
    return [jnp.asarray(w / w.sum(), jnp.float32) for w in weights]


def _time(draw, maps, repeats: int) -> float:
    draw(jax.random.key(0), maps[0]).block_until_ready()  # compile
    passes = []
    for repeat in range(repeats):
        start = time.perf_counter()
        for index, probabilities in enumerate(maps):
            draw(jax.random.key(repeat * len(maps) + index), probabilities).block_until_ready()
        passes.append((time.perf_counter() - start) / len(maps))
    return statistics.median(passes)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", type=int, default=16)
    parser.add_argument("--samples", type=int, default=1024)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    config = CliportConfig()
    maps = _maps(args.scenes, config)
    gumbel = jax.jit(lambda key, p: jax.random.categorical(key, jnp.log(p), shape=(args.samples,)))
    inverse = jax.jit(lambda key, p: cliport.sample_pixels(key, p, args.samples, config.width))
    gumbel_s, inverse_s = _time(gumbel, maps, args.repeats), _time(inverse, maps, args.repeats)
    print(f"{config.width} x {config.height} pixels, {args.samples} samples per scene, {args.scenes} scenes")
    print(f"Gumbel-max  {gumbel_s * 1e3:9.2f} ms/scene")
    print(f"inverse CDF {inverse_s * 1e3:9.2f} ms/scene  ({gumbel_s / inverse_s:.0f}x faster)")


if __name__ == "__main__":
    main()
