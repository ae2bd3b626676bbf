"""Dataset generation on a two-node Ray cluster: scaling over one node, and Ray's cost over the local pool.

    python perf/distributed_generate.py --scenes 2000

Generates the same training scenes four times, back to back, each into a new folder: a local pool
of one process and of two, a Ray cluster of one node with one CPU, and a Ray cluster of two nodes
with one CPU each (two raylets on this machine, `ray.cluster_utils.Cluster`). Wall times include
starting the workers (and the cluster's join). Prints scenes/s, the scaling efficiency of two nodes
over one, Ray's overhead over the local pool on the same CPUs, and whether every run wrote the same
bytes. `--runs` picks some of the four (Ray's runs include the cluster's start).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import shutil
import tempfile
import time
from pathlib import Path

import ocplace  # noqa: F401  (sets the headless OpenGL default before MuJoCo loads)
from ocplace.runtime import ExecutorConfig, open_executor
from ocplace.sim.dataset.config import make_config
from ocplace.sim.dataset.job import generate_dataset


def timed(out: Path, config, executor: ExecutorConfig) -> tuple[float, dict]:
    began = time.perf_counter()
    with open_executor(executor) as running:
        files = generate_dataset(out, config, executor=running, progress=False)["files"]
    return time.perf_counter() - began, files


def cluster(nodes: int, temp_dir: str):
    """A local Ray cluster of `nodes` one-CPU nodes; returns (cluster, executor config)."""
    from ray.cluster_utils import Cluster

    (Path(tempfile.gettempdir()) / "ray").mkdir(exist_ok=True)  # Cluster records its address there
    started = Cluster(
        initialize_head=True, head_node_args={"num_cpus": 1, "include_dashboard": False, "temp_dir": temp_dir}
    )
    for _ in range(nodes - 1):
        started.add_node(num_cpus=1)
    started.wait_for_nodes()
    return started, ExecutorConfig(kind="ray", address=started.address)


RUNS = {  # name: (executor kind, CPUs)
    "local pool, 1 process": ("local", 1),
    "local pool, 2 processes": ("local", 2),
    "Ray, 1 node x 1 CPU": ("ray", 1),
    "Ray, 2 nodes x 1 CPU": ("ray", 2),
}


def run(name: str, out: Path, config) -> tuple[float, dict]:
    kind, cpus = RUNS[name]
    if kind == "local":
        return timed(out, config, ExecutorConfig(workers=cpus))
    temp_dir = tempfile.mkdtemp(prefix="ocray-", dir="/tmp")
    began = time.perf_counter()
    started, executor = cluster(cpus, temp_dir)
    try:
        _, files = timed(out, config, executor)
        return time.perf_counter() - began, files  # the cluster's start counts: a command pays it too
    finally:
        started.shutdown()
        shutil.rmtree(temp_dir, ignore_errors=True)


def report(walls: dict[str, float], outputs: dict[str, dict]) -> None:
    if {"Ray, 1 node x 1 CPU", "Ray, 2 nodes x 1 CPU"} <= walls.keys():
        one, two = walls["Ray, 1 node x 1 CPU"], walls["Ray, 2 nodes x 1 CPU"]
        print(f"two nodes over one: {one / two:.2f}x, scaling efficiency {100 * one / (2 * two):.0f}%")
    if {"local pool, 2 processes", "Ray, 2 nodes x 1 CPU"} <= walls.keys():
        local, two = walls["local pool, 2 processes"], walls["Ray, 2 nodes x 1 CPU"]
        print(f"Ray (2 nodes) over the local pool (2 processes), same CPUs: {100 * (two / local - 1):+.1f}% wall")
    reference = next(iter(outputs.values()))
    print("same bytes in every run:", all(files == reference for files in outputs.values()))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=2000, help="training scenes per run")
    parser.add_argument("--keep", type=Path, help="keep the datasets here (default: a temporary folder)")
    parser.add_argument("--runs", nargs="+", choices=list(RUNS), default=list(RUNS), help="which runs, in order")
    args = parser.parse_args()
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")

    config = make_config(train=args.scenes)
    config = dataclasses.replace(config, splits=config.splits[:1])
    root = Path(args.keep or tempfile.mkdtemp(prefix="ocplace-gen-"))
    walls, outputs = {}, {}
    for index, name in enumerate(args.runs):
        walls[name], outputs[name] = run(name, root / f"run-{index}", config)
        print(f"{name}: {walls[name]:.1f} s = {args.scenes / walls[name]:.2f} scenes/s", flush=True)
    report(walls, outputs)
    if args.keep is None:
        shutil.rmtree(root)


if __name__ == "__main__":
    main()
