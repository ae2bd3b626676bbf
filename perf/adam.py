"""Which Adam trains faster: optax's `adam` or the one-pass Adam of `train/optim.py`, in the same run.

Times the fused training steps (`lax.scan`, as every training runs them) of Ours' adapters at batch 1
(the paper's schedule) and of no_llm at its recipe's batch of 32, on synthetic inputs of the real
shapes (D = 512), with each Adam on the same learning-rate schedule. The two Adams alternate, so a
change of load on a shared machine hits both. Compilation is excluded.
Usage: `python perf/adam.py [--steps 2000] [--repeats 5] [--cpus 2]`.
"""

from __future__ import annotations

import argparse
import datetime
import os
import statistics
import time

from ocplace.runtime.width import TRAIN_CPUS, pin_jax_width

DIM = 512


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=2_000, help="steps per timed chunk")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--cpus", type=int, default=TRAIN_CPUS, help="JAX's width, as the trainings' (default 2)")
    args = parser.parse_args()
    pin_jax_width(args.cpus)
    load = " ".join(f"{x:.1f}" for x in os.getloadavg())
    print(f"{datetime.datetime.now():%Y-%m-%d %H:%M}, JAX {args.cpus} CPUs wide, load average {load}")
    for problem, (loss, params, data, batch) in problems().items():
        timings = time_adams(loss, params, data, batch, args.steps, args.repeats)
        line = ", ".join(f"{name} {statistics.median(us):.1f} us/step" for name, us in timings.items())
        print(f"{problem} (batch {batch}): {line} (median of {args.repeats})")


def problems() -> dict:
    """Per method: `(loss(params, batch), initial params, data, batch size)` of its training step."""
    import jax
    import numpy as np

    from ocplace.methods.no_llm.model import NoLlmConfig, init_params, loss_terms
    from ocplace.models.adapters import AdapterConfig, init_adapters
    from ocplace.models.grounding import adapted_logits, grounding_loss

    rng = np.random.default_rng(0)
    scenes = 2_000

    def normal(*shape):
        return rng.normal(size=(scenes, *shape)).astype(np.float32)

    adapters = AdapterConfig(DIM)
    targets = rng.integers(6, size=(scenes, 2)).astype(np.int32)
    ours_data = (normal(6, DIM), np.ones((scenes, 6), bool), normal(2, DIM), np.ones((scenes, 2), bool), targets)

    def ours_loss(params, batch):
        visual, visual_mask, text, text_mask, targets = batch
        return grounding_loss(adapted_logits(adapters, params, text, visual, visual_mask, 100.0), targets, text_mask)

    no_llm = NoLlmConfig(dim=DIM, hidden=256)
    no_llm_data = {
        "visual": normal(6, DIM),
        "visual_mask": np.ones((scenes, 6), bool),
        "sentence": normal(DIM),
        "targets": rng.integers(6, size=(scenes, 2)).astype(np.int32),
        "target_mask": np.ones((scenes, 2), bool),
        "relations": rng.integers(8, size=(scenes, 2)).astype(np.int32),
    }

    def no_llm_loss(params, batch):
        reference, relation = loss_terms(no_llm, params, batch, 100.0)
        return reference + relation

    return {
        "ours": (ours_loss, init_adapters(adapters, jax.random.key(0)), ours_data, 1),
        "no_llm": (no_llm_loss, init_params(no_llm, jax.random.key(0)), no_llm_data, 32),
    }


def time_adams(loss, params, data, batch: int, steps: int, repeats: int) -> dict[str, list[float]]:
    """Microseconds per step of each Adam, `repeats` times, alternating."""
    import jax
    import numpy as np
    import optax

    from ocplace.train import optim

    schedule = optim.warmup_cosine(1e-4, 1_000, 200_000)
    adams = {"optax.adam": optax.adam(schedule), "train/optim.py adam": optim.adam(schedule)}
    data = jax.device_put(data)
    scenes = len(jax.tree_util.tree_leaves(data)[0])
    indices = jax.numpy.asarray(np.random.default_rng(0).integers(scenes, size=(steps, batch)), np.int32)

    def chunk_of(adam):
        def step(state, rows):
            params, opt_state = state
            value, grads = jax.value_and_grad(loss)(params, jax.tree_util.tree_map(lambda a: a[rows], data))
            updates, opt_state = adam.update(grads, opt_state, params)
            return (optax.apply_updates(params, updates), opt_state), value

        return jax.jit(lambda state: jax.lax.scan(step, state, indices))

    chunks = {name: chunk_of(adam) for name, adam in adams.items()}
    states = {name: (params, adam.init(params)) for name, adam in adams.items()}
    for name, chunk in chunks.items():
        jax.block_until_ready(chunk(states[name]))  # compiles
    timings: dict[str, list[float]] = {name: [] for name in adams}
    for _ in range(repeats):
        for name, chunk in chunks.items():
            began = time.perf_counter()
            states[name] = jax.block_until_ready(chunk(states[name])[0])
            timings[name].append((time.perf_counter() - began) / steps * 1e6)
    return timings


if __name__ == "__main__":
    main()
