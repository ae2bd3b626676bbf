"""Episodes per second of the Gymnasium environment, from a dataset and with scenes generated on the fly.

`python perf/gym_env.py` first generates `--scenes` scenes of the `seen` split with the library's own
job (what `ocplace generate` runs), timing its scenes/s; then it plays episodes (reset, then a step
scored with the metric, no physical check) from that dataset, then the same scenes generated on the
fly, with one environment and with the vector environment's two workers beside `generate` with two
workers. Each timing runs in a fresh process, with its start-up (the library, the MuJoCo arena,
worker processes) inside, as in the command. Targets: >= 50 episodes/s from a dataset on 2 cores;
generated scenes within 20% of `generate`'s scenes/s (a ratio >= 0.8).
"""

from __future__ import annotations

import argparse
import concurrent.futures
import multiprocessing
import tempfile
import time
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np

import ocplace  # noqa: F401  (sets the headless OpenGL default before MuJoCo loads)
from ocplace.runtime import ExecutorConfig, open_executor
from ocplace.sim.dataset.config import make_config
from ocplace.sim.dataset.job import generate_dataset
from ocplace.sim.env import ENV_ID

CENTRE = np.zeros(2)  # the table's centre: the action does not change the cost of the metric


def generate_rate(out: Path, config, workers: int) -> float:
    """Scenes/s of the dataset job on the `seen` split (start-up included)."""
    start = time.perf_counter()
    with open_executor(ExecutorConfig(workers=workers)) as executor:
        manifest = generate_dataset(out, config, splits=["seen"], executor=executor, progress=False)
    return sum(manifest["counts"]["seen"].values()) / (time.perf_counter() - start)


def single_rate(episodes: int, **kwargs) -> float:
    """Episodes/s of one environment: make, then `episodes` x (reset, step)."""
    start = time.perf_counter()
    env = gymnasium.make(ENV_ID, split="seen", **kwargs)
    env.reset(seed=0)
    env.step(CENTRE)
    for _ in range(episodes - 1):
        env.reset()
        env.step(CENTRE)
    env.close()
    return episodes / (time.perf_counter() - start)


def vector_rate(episodes: int, workers: int, **kwargs) -> tuple[float, float]:
    """Episodes/s of the vector environment (each step ends `workers` episodes and resets them): in all,
    and after the workers started and showed their first scenes."""
    start = time.perf_counter()
    env = gymnasium.make_vec(ENV_ID, num_envs=workers, split="seen", **kwargs)
    env.reset(seed=0)
    started = time.perf_counter()
    for _ in range(episodes // workers):
        env.step(np.zeros((workers, 2)))
    env.close()
    played, end = workers * (episodes // workers), time.perf_counter()
    return played / (end - start), (played - workers) / (end - started)


def fresh(measure, *args, **kwargs) -> Any:
    """`measure(*args, **kwargs)` in a new process, so that no timing inherits another's imports or caches."""
    with concurrent.futures.ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
        return pool.submit(measure, *args, **kwargs).result()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=40, help="scenes generated, each way")
    parser.add_argument("--episodes", type=int, default=400, help="episodes played from the dataset")
    args = parser.parse_args()

    config = make_config(test=args.scenes)
    with tempfile.TemporaryDirectory() as tmp:
        dataset = Path(tmp) / "one-worker"
        generated_1 = fresh(generate_rate, dataset, config, workers=1)
        from_dataset = fresh(single_rate, args.episodes, dataset=dataset)
        from_dataset_2 = fresh(vector_rate, args.episodes, 2, dataset=dataset)
        on_the_fly_1 = fresh(single_rate, args.scenes, generator=config)
        generated_2 = fresh(generate_rate, Path(tmp) / "two-workers", config, workers=2)
        on_the_fly_2 = fresh(vector_rate, args.scenes, 2, generator=config)
    print(f"from a dataset, one env: {from_dataset:.1f} episodes/s (target >= 50)")
    print(
        f"from a dataset, vector env with 2 workers: {from_dataset_2[0]:.1f} episodes/s "
        f"({from_dataset_2[1]:.1f} after the workers' start-up)"
    )
    for workers, generated, on_the_fly in ((1, generated_1, on_the_fly_1), (2, generated_2, on_the_fly_2[0])):
        print(
            f"generated on the fly, {workers} process(es): {on_the_fly:.2f} episodes/s; the dataset job with "
            f"{workers} worker(s): {generated:.2f} scenes/s; ratio {on_the_fly / generated:.2f} (target >= 0.8)"
        )


if __name__ == "__main__":
    main()
