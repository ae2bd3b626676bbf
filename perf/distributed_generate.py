"""Dataset generation on a two-node Ray cluster: scaling over one node, and Ray's cost over the local pool.

    python perf/distributed_generate.py --scenes 2000

Generates the same training scenes four times, back to back, each into a new folder: a local pool
of one process and of two, a Ray cluster of one node with one CPU, and a Ray cluster of two nodes
with one CPU each (two raylets on this machine, `ray.cluster_utils.Cluster`). Wall times include
starting the workers (and the cluster's join). Prints scenes/s, the scaling efficiency of two nodes
over one, Ray's overhead over the local pool on the same CPUs, and whether every run wrote the same
bytes. `--two-cpus-only` makes the two two-CPU runs only: Ray's overhead, not its scaling.
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=2000, help="training scenes per run")
    parser.add_argument("--keep", type=Path, help="keep the datasets here (default: a temporary folder)")
    parser.add_argument(
        "--two-cpus-only",
        action="store_true",
        help="only the two-CPU runs (Ray's overhead over the local pool), about a third of the time: no scaling",
    )
    args = parser.parse_args()
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")

    config = make_config(train=args.scenes)
    config = dataclasses.replace(config, splits=config.splits[:1])
    root = Path(args.keep or tempfile.mkdtemp(prefix="ocplace-gen-"))
    walls, outputs = {}, {}
    counts = (2,) if args.two_cpus_only else (1, 2)
    for name, workers in [(f"local pool, {n} process{'es' if n > 1 else ''}", n) for n in counts]:
        walls[name], outputs[name] = timed(root / f"local-{workers}", config, ExecutorConfig(workers=workers))
        print(f"{name}: {walls[name]:.1f} s = {args.scenes / walls[name]:.2f} scenes/s", flush=True)
    for nodes in counts:
        name = f"Ray, {nodes} node(s) x 1 CPU"
        temp_dir = tempfile.mkdtemp(prefix="ocray-", dir="/tmp")
        began = time.perf_counter()
        started, executor = cluster(nodes, temp_dir)
        try:
            _, outputs[name] = timed(root / f"ray-{nodes}", config, executor)
            walls[name] = time.perf_counter() - began  # the cluster's start counts: a command pays it too
        finally:
            started.shutdown()
            shutil.rmtree(temp_dir, ignore_errors=True)
        print(f"{name}: {walls[name]:.1f} s = {args.scenes / walls[name]:.2f} scenes/s (cluster start included)")
    two = walls["Ray, 2 node(s) x 1 CPU"]
    if not args.two_cpus_only:
        one = walls["Ray, 1 node(s) x 1 CPU"]
        print(f"two nodes over one: {one / two:.2f}x, scaling efficiency {100 * one / (2 * two):.0f}%")
    local = walls["local pool, 2 processes"]
    print(f"Ray (2 nodes) over the local pool (2 processes), same CPUs: {100 * (two / local - 1):+.1f}% wall")
    reference = outputs["local pool, 2 processes"]
    print("same bytes in every run:", all(files == reference for files in outputs.values()))
    if args.keep is None:
        shutil.rmtree(root)


if __name__ == "__main__":
    main()
