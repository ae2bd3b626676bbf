"""Adapter training speed: the paper's 200K-step batch-1 schedule on cached D = 512 features.

Times the steps fused with `lax.scan` (what `ocplace train` runs) against a plain Python loop that
calls one jitted step at a time, in the same run on the same synthetic features; compilation is
excluded from both. The loop is timed on `--loop-steps` steps and extrapolated.
`--cpus N` starts JAX sized to N CPUs (`pin_jax_width`, as `ocplace train` does); on a machine
shared with other jobs, `--cpus 1` avoids XLA's intra-op fork-join waiting for
a busy core inside the fused loop (see docs/performance.md).
Usage: `python perf/train.py [--steps 200000] [--chunk-steps 2000] [--loop-steps 5000] [--cpus N]`.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import os
import sys
import time
from pathlib import Path

from ocplace.methods.ours.recipe import default_config
from ocplace.runtime.width import pin_jax_width


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=200_000)
    parser.add_argument("--chunk-steps", type=int, default=default_config().schedule.chunk_steps)
    parser.add_argument("--loop-steps", type=int, default=5_000)
    parser.add_argument("--batch-size", type=int, default=1)
    parser.add_argument("--dim", type=int, default=512)
    parser.add_argument("--scenes", type=int, default=2_000)
    parser.add_argument("--cpus", type=int, help="pin to this many CPUs (default: all)")
    args = parser.parse_args()
    if args.cpus:
        pin_jax_width(args.cpus)  # as `ocplace train` and `reproduce`'s tasks: XLA sized to N CPUs
    run(args)


def run(args) -> None:
    import functools

    import jax
    import jax.numpy as jnp

    from ocplace.methods.ours.train import init_state, jit_train_chunk, jit_train_step
    from ocplace.models.adapters import AdapterConfig, count_parameters
    from ocplace.train import optim
    from ocplace.train.batches import batch_indices

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))  # the test support: synthetic inputs
    from synthetic_features import synthetic_features

    schedule = dataclasses.replace(
        default_config().schedule, steps=args.steps, batch_size=args.batch_size, chunk_steps=args.chunk_steps
    )
    config = dataclasses.replace(default_config(), schedule=schedule)
    features = synthetic_features(args.scenes, args.dim)
    adapter_config = AdapterConfig(args.dim, config.adapters.reduction, config.adapters.residual_ratio)
    optimizer = optim.make(schedule)
    fresh_state = functools.partial(init_state, adapter_config, optimizer, 0)
    scale = features.info.logit_scale
    train_chunk = functools.partial(jit_train_chunk, adapter_config, config, scale)
    train_step = functools.partial(jit_train_step, adapter_config, config, scale)
    data = jax.device_put(features.arrays())
    indices = jnp.asarray(batch_indices(features.num_scenes, 0, 0, args.steps, args.batch_size))
    load = " ".join(f"{x:.1f}" for x in os.getloadavg())
    print(
        f"{datetime.datetime.now():%Y-%m-%d %H:%M}, JAX {args.cpus or len(os.sched_getaffinity(0))} of "
        f"{os.cpu_count()} CPUs wide, "
        f"load average {load} (other jobs share this machine)"
    )
    print(
        f"D = {args.dim}, {count_parameters(fresh_state()[0]):,} trainable parameters, {args.scenes} scenes, "
        f"batch {args.batch_size}, {args.steps:,} steps in chunks of {args.chunk_steps}"
    )

    fused_s, fused_cpu_s = time_fused(train_chunk, fresh_state, data, indices, args.chunk_steps)
    loop_s = time_loop(train_step, fresh_state, data, indices[: args.loop_steps])
    fused_us, loop_us = fused_s / args.steps * 1e6, loop_s / args.loop_steps * 1e6
    print(
        f"lax.scan chunks : {fused_s:7.1f} s for {args.steps:,} steps ({fused_us:.1f} us/step; "
        f"{fused_cpu_s:.1f} CPU-seconds)"
    )
    print(
        f"per-step loop   : {loop_us * args.steps / 1e6:7.1f} s extrapolated from {args.loop_steps:,} steps "
        f"({loop_us:.1f} us/step)"
    )
    print(f"speed-up of the fused loop: {loop_us / fused_us:.2f}x")


def time_fused(train_chunk, fresh_state, data, indices, chunk: int) -> tuple[float, float]:
    """Wall and CPU seconds for all of `indices` in chunks, after compiling every chunk length used."""
    import jax

    for length in {min(chunk, len(indices) - start) for start in range(0, len(indices), chunk)}:
        jax.block_until_ready(train_chunk(fresh_state(), data, indices[:length]))
    state = jax.block_until_ready(fresh_state())
    start, start_cpu = time.perf_counter(), time.process_time()
    for begin in range(0, len(indices), chunk):
        state, _ = train_chunk(state, data, indices[begin : begin + chunk])
    jax.block_until_ready(state)
    return time.perf_counter() - start, time.process_time() - start_cpu


def time_loop(train_step, fresh_state, data, indices) -> float:
    import jax

    state, _ = train_step(fresh_state(), data, indices[0])
    jax.block_until_ready(state)
    rows = [indices[i] for i in range(len(indices))]
    start = time.perf_counter()
    for row in rows:
        state, _ = train_step(state, data, row)
    jax.block_until_ready(state)
    return time.perf_counter() - start


if __name__ == "__main__":
    main()
