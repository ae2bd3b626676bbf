"""A policy folder on the command line: `ocplace place --policy DIR` per scene after load, against its 3 s target.

Times, in one process: loading the folder (`PlacementPolicy.from_pretrained`), then `place` on each of the first
`--scenes` scenes of `--split` (the first call compiles and is reported apart), as `ocplace place --policy` runs
it; and, as the reference measured in the same run, the same scenes through `from_run` on the run and backbone it
was exported from when `--run` is given (the two must place to the same bits).
Usage: `python perf/policy_folder.py --policy out/demo/policy --dataset out/demo/dataset [--run RUN] [--scenes 8]`.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import jax
import numpy as np

from ocplace.models.policy import PlacementPolicy
from ocplace.sim.dataset.job import listed_scenes

TARGET_S = 3.0


def timed_places(policy, scenes) -> tuple[float, list[float], list]:
    """(first call's seconds, the others' seconds, placements)."""
    walls, placements = [], []
    for index, scene in enumerate(scenes):
        began = time.perf_counter()
        placements.append(policy.place_many([scene], jax.random.key(index))[0])
        walls.append(time.perf_counter() - began)
    return walls[0], walls[1:], placements


def main() -> int:
    from ocplace.methods.policy_method import scene_input

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy", type=Path, required=True)
    parser.add_argument("--dataset", type=Path, required=True)
    parser.add_argument("--split", default="seen")
    parser.add_argument("--scenes", type=int, default=8)
    parser.add_argument("--run", type=Path, help="the run it was exported from: places the same scenes as reference")
    args = parser.parse_args()
    scenes = [scene_input(scene.read()) for scene in listed_scenes(args.dataset, args.split)[: args.scenes]]
    began = time.perf_counter()
    policy = PlacementPolicy.from_pretrained(args.policy)
    load_s = time.perf_counter() - began
    first, rest, placements = timed_places(policy, scenes)
    median = statistics.median(rest)
    print(f"policy folder {args.policy}: load {load_s:.2f} s, first scene {first:.2f} s (compiles)")
    print(f"per scene after load: median {median:.3f} s, max {max(rest):.3f} s over {len(rest)} scenes")
    verdict = "met" if max(rest) <= TARGET_S else "MISSED"
    print(f"target <= {TARGET_S:g} s per scene: {verdict} (median {TARGET_S / median:.0f}x under it)")
    if args.run is not None:
        from ocplace.methods.export import backbone_of
        from ocplace.models.backbone import load_backbone
        from ocplace.models.trained_adapters import load_adapters

        adapters = load_adapters(args.run)
        reference = PlacementPolicy.from_run(load_backbone(backbone_of(adapters)), adapters)
        _, reference_rest, expected = timed_places(reference, scenes)
        same = all(
            a.failure == b.failure and (a.mode is None or np.array_equal(a.mode, b.mode))
            for a, b in zip(expected, placements, strict=True)
        )
        print(f"from_run on {args.run}: median {statistics.median(reference_rest):.3f} s per scene; same bits: {same}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
