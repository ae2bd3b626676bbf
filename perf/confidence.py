"""How confident the grounding is, to choose the policy's low-confidence threshold.

For every tuple of a test split: the top probability when the grounding is right, when it is
wrong, and when the reference is absent (its phrase replaced by the name of an object from
another scene that is not in this one). Prints quantiles and, per candidate threshold, the share
of right groundings refused and of absent references caught.
Usage: `python perf/confidence.py --dataset DIR --backbone SPEC [--adapters RUN] [--split seen]`.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import jax
import numpy as np

THRESHOLDS = (0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9)


def absent_scene(scene, record, names: list[str], rng: np.random.Generator):
    """`scene` with its first reference renamed to an object that is not in it, or None."""
    present = {obj.human_name for obj in record.objects}
    reference = record.tuples[0].reference_name
    choices = [name for name in names if name not in present]
    if reference == "table" or reference not in scene.instruction or not choices:
        return None
    return dataclasses.replace(scene, instruction=scene.instruction.replace(reference, str(rng.choice(choices)), 1))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", type=Path, required=True)
    parser.add_argument("--backbone", default="offline")
    parser.add_argument("--adapters", type=Path, help="run directory (default: zero-shot)")
    parser.add_argument("--split", default="seen")
    args = parser.parse_args()

    from ocplace.methods.policy_method import scene_input
    from ocplace.models.backbone import load_backbone
    from ocplace.models.placement.sampler import SamplerConfig
    from ocplace.models.policy import PlacementPolicy
    from ocplace.sim.dataset.job import listed_scenes

    records = [scene.read() for scene in listed_scenes(args.dataset, args.split)]
    policy = PlacementPolicy.from_run(
        load_backbone(args.backbone), args.adapters, threshold=0.0, sampler=SamplerConfig(num_samples=16)
    )
    scenes = [scene_input(r) for r in records]
    names = sorted({obj.human_name for r in records for obj in r.objects})
    rng = np.random.default_rng(0)
    absent = [(i, absent_scene(s, r, names, rng)) for i, (s, r) in enumerate(zip(scenes, records))]
    absent = [s for _, s in absent if s is not None]
    right, wrong, missing = [], [], []
    for record, placement in zip(records, policy.place_many(scenes, jax.random.key(0), progress=True)):
        for truth, ref in zip(record.tuples, placement.references):
            (right if ref.token == truth.token_index else wrong).append(ref.probability)
    for placement in policy.place_many(absent, jax.random.key(1), progress=True):
        if placement.references:
            missing.append(placement.references[0].probability)
    print(f"{args.split}: {len(right)} right, {len(wrong)} wrong groundings; {len(missing)} absent references")
    for name, values in (("right", right), ("wrong", wrong), ("absent", missing)):
        if values:
            quantiles = np.percentile(values, [1, 5, 25, 50, 75])
            print(
                f"  top probability, {name:<6}: p1 {quantiles[0]:.3f} p5 {quantiles[1]:.3f} p25 {quantiles[2]:.3f} "
                f"median {quantiles[3]:.3f} p75 {quantiles[4]:.3f}"
            )
    for threshold in THRESHOLDS:
        refused = np.mean(np.asarray(right) < threshold) if right else float("nan")
        caught = np.mean(np.asarray(missing) < threshold) if missing else float("nan")
        print(
            f"  threshold {threshold:.1f}: refuses {refused:6.1%} of right groundings, catches {caught:6.1%} of "
            "absent references"
        )


if __name__ == "__main__":
    main()
