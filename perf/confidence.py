"""Choosing the robot's refusal gate (`ocplace.vocabulary.GATE_THRESHOLD`) on the dev splits: rule G of
docs/settings.md, never a test subset.

1. A selection run of Ours: the experiment's adapter recipe trained on the training split's features with
   the seen colour variants held out (`models.features.without_objects`), so `dev_colour` shows objects its
   adapters never saw (resumable, in --work).
2. Every reference of `dev_seen` and `dev_colour` grounded at its argmax by the policy on that run (no
   refusal); right = the reference's token. Also, per scene, one reference swapped for the name of an
   object that is not in it (absent), which a gate should catch.
3. The threshold: the largest of 0.05, 0.10, ..., 0.95 that refuses at most 5% of the right groundings
   (table references included), pooled over the two splits. Printed with the share of right object
   references it refuses, and of wrong groundings and absent references it catches.

Usage: `python perf/confidence.py --dataset DATA --dev DEV --backbone SPEC [--experiment default] --out
gate.json` where DATA holds the training split and DEV the dev splits (`ocplace generate --out DEV --split
dev_seen --dev 400`, then `--split dev_colour`).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import jax
import numpy as np

import ocplace  # noqa: F401  (sets the headless OpenGL default before MuJoCo loads)

THRESHOLDS = tuple(round(0.05 * k, 2) for k in range(1, 20))
MAX_REFUSED = 0.05  # share of right groundings the gate may refuse
DEV_SPLITS = ("dev_seen", "dev_colour")


def absent_scene(scene, record, names: list[str], rng: np.random.Generator):
    """`scene` with its first reference renamed to an object that is not in it, or None."""
    present = {obj.human_name for obj in record.objects}
    reference = record.tuples[0].reference_name
    choices = [name for name in names if name not in present]
    if reference == "table" or reference not in scene.instruction or not choices:
        return None
    return dataclasses.replace(scene, instruction=scene.instruction.replace(reference, str(rng.choice(choices)), 1))


def choose(right: np.ndarray) -> float:
    """Rule G: the largest threshold refusing at most `MAX_REFUSED` of the right groundings' probabilities."""
    allowed = [t for t in THRESHOLDS if np.mean(right < t) <= MAX_REFUSED]
    return max(allowed) if allowed else 0.0


def selection_run(data: Path, backbone_spec: str, experiment: str, work: Path) -> Path:
    """Ours' recipe trained without the seen colour variants; returns the run directory."""
    from ocplace import configs
    from ocplace.methods.ours.recipe import OursRecipe
    from ocplace.methods.ours.train import train_ours
    from ocplace.models.backbone import load_backbone
    from ocplace.models.features import featurize_split, load_features, without_objects
    from ocplace.sim.library import load_library
    from ocplace.sim.library.library import colour_variants

    backbone = load_backbone(backbone_spec)
    features = load_features(featurize_split(data, "train", backbone), backbone.fingerprint)
    held = without_objects(features, data, "train", colour_variants(load_library()))
    train_ours(held, work, configs.get(experiment).recipe_as("ours", OursRecipe))
    return work


def groundings(policy, dev: Path, key) -> dict[str, list[float]]:
    """Top probabilities of right and wrong groundings (also the right ones of object references alone), and of
    absent references, over the dev splits. A parsed reference is matched to the scene's tuple of the same
    phrase; one without such a tuple counts as wrong."""
    from ocplace.eval.harness import reference_key
    from ocplace.methods.policy_method import scene_input
    from ocplace.sim.dataset.job import listed_scenes

    found: dict[str, list[float]] = {"right": [], "right_objects": [], "wrong": [], "absent": []}
    rng = np.random.default_rng(0)
    for split in DEV_SPLITS:
        records = [scene.read() for scene in listed_scenes(dev, split)]
        scenes = [scene_input(record) for record in records]
        for record, placement in zip(records, policy.place_many(scenes, key, progress=True)):
            truth = {reference_key(t.reference_name): t.token_index for t in record.true_tuples()}
            for reference in placement.references:
                right = truth.get(reference_key(reference.phrase)) == reference.token
                found["right" if right else "wrong"].append(reference.probability)
                if right and not reference.is_table:
                    found["right_objects"].append(reference.probability)
        names = sorted({obj.human_name for record in records for obj in record.objects})
        absent = [absent_scene(scene, record, names, rng) for scene, record in zip(scenes, records)]
        for placement in policy.place_many([s for s in absent if s is not None], key, progress=True):
            if placement.references:
                found["absent"].append(placement.references[0].probability)
    return found


def selection_arguments(description: str, out: str) -> argparse.ArgumentParser:
    """The arguments of a choice made with a selection run on the dev splits (this script's, `joint_selection.py`)."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--dataset", type=Path, required=True, help="dataset folder holding the training split")
    parser.add_argument("--dev", type=Path, required=True, help="dataset folder holding dev_seen and dev_colour")
    parser.add_argument("--backbone", default="offline")
    parser.add_argument("--experiment", default="default", help="whose adapter recipe the selection run trains")
    parser.add_argument("--work", type=Path, default=Path("out/gate_selection"), help="the selection run (shared)")
    parser.add_argument("--out", type=Path, default=Path(out))
    return parser


def main() -> None:
    args = selection_arguments(__doc__.splitlines()[0], "gate.json").parse_args()

    from ocplace.models.backbone import load_backbone
    from ocplace.models.placement.sampler import SamplerConfig
    from ocplace.models.policy import PlacementPolicy
    from ocplace.sim.dataset.job import check_dev_scenes, read_manifest

    check_dev_scenes(args.dev, read_manifest(args.dev), read_manifest(args.dataset))  # no dev scene is a test one
    run = selection_run(args.dataset, args.backbone, args.experiment, args.work)
    policy = PlacementPolicy.from_run(
        load_backbone(args.backbone), run, threshold=0.0, sampler=SamplerConfig(num_samples=16)
    )
    found = {kind: np.asarray(values) for kind, values in groundings(policy, args.dev, jax.random.key(0)).items()}
    threshold = choose(found["right"])
    report = {
        "threshold": threshold,
        "rule": f"largest of {THRESHOLDS[0]}..{THRESHOLDS[-1]} refusing <= {MAX_REFUSED:.0%} of right groundings",
        "counts": {kind: len(values) for kind, values in found.items()},
        "per_threshold": {
            str(t): {kind: float(np.mean(values < t)) if len(values) else None for kind, values in found.items()}
            for t in THRESHOLDS
        },
        "backbone": args.backbone,
        "run": str(run),
    }
    for t in THRESHOLDS:
        shares = report["per_threshold"][str(t)]
        print(
            f"threshold {t:.2f}: refuses {shares['right']:6.1%} of right groundings ({shares['right_objects']:6.1%} "
            f"of object ones), catches {shares['wrong']:6.1%} of wrong ones and {shares['absent']:6.1%} of absent "
            "references"
        )
    print(f"chosen: {threshold} ({report['counts']})")
    args.out.write_text(json.dumps(report, indent=2) + "\n")


if __name__ == "__main__":
    main()
