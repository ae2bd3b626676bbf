"""What the joint decision costs a robot: `PlacementPolicy.place` per scene with the argmax and the joint decision.

The same trained policy, the same scenes (the first `--scenes` object-referenced scenes of each test subset of
`--dataset`), one `place` call per scene as a robot makes it, both decisions interleaved scene by scene so that
both see the same load; every shape compiled before timing. Printed: the median per scene of each and their ratio
(issue 57's target: joint <= 1.5 x argmax), and the same for the batched `place_many` of all the scenes at once,
as an evaluation runs them.

Usage: `python perf/joint_inference.py --dataset DATA --policy FOLDER [--scenes 20]` (FOLDER: a policy folder,
`out/demo/policy` after `make demo`).
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import os
import statistics
import time
from pathlib import Path

import jax

import ocplace  # noqa: F401  (sets the headless OpenGL default before MuJoCo loads)
from ocplace.methods.policy_method import scene_input
from ocplace.models.inference_settings import Decision
from ocplace.models.policy import PlacementPolicy
from ocplace.sim.dataset.job import listed_scenes
from ocplace.vocabulary import TEST_SUBSETS


def timed(policy: PlacementPolicy, scenes, key) -> float:
    began = time.perf_counter()
    policy.place_many(scenes, key)
    return time.perf_counter() - began


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", type=Path, required=True)
    parser.add_argument("--policy", type=Path, required=True, help="a policy folder")
    parser.add_argument("--scenes", type=int, default=20, help="object-referenced scenes per test subset")
    parser.add_argument("--k", type=int, default=Decision("joint").top_k, help="the joint decision's top_k")
    args = parser.parse_args()

    records = []
    for subset in TEST_SUBSETS:
        found = [scene.read() for scene in listed_scenes(args.dataset, subset)]
        records += [record for record in found if record.level != "table"][: args.scenes]
    scenes = [scene_input(record) for record in records]
    argmax = PlacementPolicy.from_pretrained(args.policy, decision=Decision("argmax"))
    joint = dataclasses.replace(argmax, decision=Decision("joint", args.k))
    key = jax.random.key(0)
    for policy in (argmax, joint):  # compile every shape the timed calls meet
        policy.place_many(scenes, key)
        for scene in scenes:
            policy.place_many([scene], key)
    times: dict[str, list[float]] = {"argmax": [], "joint": []}
    for scene in scenes:
        times["argmax"].append(timed(argmax, [scene], key))
        times["joint"].append(timed(joint, [scene], key))
    batched = {
        name: timed(policy, scenes, key) / len(scenes) for name, policy in (("argmax", argmax), ("joint", joint))
    }
    median = {name: statistics.median(values) for name, values in times.items()}
    print(
        f"{datetime.datetime.now():%Y-%m-%d %H:%M}, {os.cpu_count()} CPUs, load average "
        f"{' '.join(f'{x:.1f}' for x in os.getloadavg())}; {len(scenes)} object-referenced scenes, k = {args.k}"
    )
    print(
        f"one place call per scene, median: argmax {1000 * median['argmax']:.1f} ms, joint "
        f"{1000 * median['joint']:.1f} ms: joint / argmax = {median['joint'] / median['argmax']:.2f}x (target <= 1.5x)"
    )
    print(
        f"place_many of all scenes, per scene: argmax {1000 * batched['argmax']:.1f} ms, joint "
        f"{1000 * batched['joint']:.1f} ms: {batched['joint'] / batched['argmax']:.2f}x"
    )


if __name__ == "__main__":
    main()
