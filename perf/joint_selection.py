"""Choosing the joint decision's `top_k`, and whether it becomes the robot's default, on the dev splits: rule J of
docs/settings.md, never a test subset.

1. A selection run of Ours (`confidence.selection_run`: the experiment's adapter recipe on the training split's
   features with the seen colour variants held out, as rules A and G).
2. Every scene of `dev_seen` and `dev_colour` placed by Ours' policy on that run and by the zero-shot policy (w/o
   Adapter), each with the argmax decision and with the joint one at every candidate k; the paper's protocol (no
   refusal); scored as Table I scores a scene (the harness's `score_scene`: success of the mode). The crops are
   encoded once (`SharedFeatures`): the candidates differ only in their decision and sampling.
3. For each policy, k: the candidate with the highest success on the two splits pooled (a tie: the smaller k).
   The joint decision becomes the robot's default when Ours' pooled success at its k beats the argmax decision's
   by more than one standard error of the paired difference and loses no more than one point on either split.

Usage: `python perf/joint_selection.py --dataset DATA --dev DEV --backbone SPEC [--experiment default] --out
joint.json` (DATA holds the training split, DEV the dev splits: `ocplace generate --out DEV --split dev_seen --dev
400 --test-dataset DATA`, then `--split dev_colour`).
"""

from __future__ import annotations

import json
import time
from typing import Any

import jax
import numpy as np
from confidence import DEV_SPLITS, selection_arguments, selection_run

import ocplace  # noqa: F401  (sets the headless OpenGL default before MuJoCo loads)

CANDIDATES = (2, 3, 5)
MAX_SPLIT_LOSS = 0.01  # the joint decision may lose at most one point on either dev split
SAMPLES = 16  # the mode decides success; a few samples keep the sampler's work small


def place_and_score(policy, records, key) -> tuple[np.ndarray, list[str | None], float]:
    """(success of the mode per scene, each scene's decision, seconds): the policy on every record, scored."""
    from ocplace.eval.harness import score_scene
    from ocplace.methods.policy_method import output_of, scene_input

    began = time.perf_counter()
    placements = policy.place_many([scene_input(record) for record in records], key, progress=True)
    wall = time.perf_counter() - began
    outputs = [output_of(placement) for placement in placements]
    successes = np.array([score_scene(record, output).success for record, output in zip(records, outputs)])
    return successes, [output.decision for output in outputs], wall


def choose_k(pooled: dict[int, float]) -> int:
    """Rule J: the candidate of the highest pooled success; a tie goes to the smaller k."""
    return min(pooled, key=lambda k: (-pooled[k], k))


def becomes_default(joint: np.ndarray, argmax: np.ndarray, splits: np.ndarray) -> dict[str, object]:
    """Rule J's test of the joint decision against argmax on the same scenes (per-scene success arrays)."""
    difference = joint.astype(float) - argmax
    standard_error = float(difference.std(ddof=1) / np.sqrt(len(difference)))
    per_split = {split: float(difference[splits == split].mean()) for split in DEV_SPLITS}
    wins = float(difference.mean()) > standard_error and min(per_split.values()) >= -MAX_SPLIT_LOSS
    return {
        "difference": float(difference.mean()),
        "standard_error": standard_error,
        "per_split": per_split,
        "default": bool(wins),
    }


def main() -> None:
    args = selection_arguments(__doc__.splitlines()[0], "joint.json").parse_args()

    from ocplace.models.backbone import load_backbone
    from ocplace.models.inference_settings import Decision
    from ocplace.models.placement.sampler import SamplerConfig
    from ocplace.models.policy import PlacementPolicy
    from ocplace.models.shared_features import SharedFeatures
    from ocplace.sim.dataset.job import check_dev_scenes, listed_scenes, read_manifest

    check_dev_scenes(args.dev, read_manifest(args.dev), read_manifest(args.dataset))  # no dev scene is a test one
    run = selection_run(args.dataset, args.backbone, args.experiment, args.work)
    backbone = SharedFeatures(load_backbone(args.backbone))
    records = [scene.read() for split in DEV_SPLITS for scene in listed_scenes(args.dev, split)]
    splits = np.array([record.split for record in records])
    decisions = {"argmax": Decision("argmax"), **{f"joint@{k}": Decision("joint", k) for k in CANDIDATES}}
    report: dict[str, Any] = {"backbone": args.backbone, "run": str(run), "candidates": list(CANDIDATES)}
    for row, adapters in (("ours", run), ("no_adapter", None)):
        scores = {}
        for name, decision in decisions.items():
            policy = PlacementPolicy.from_run(
                backbone, adapters, threshold=0.0, sampler=SamplerConfig(num_samples=SAMPLES), decision=decision
            )
            success, chosen, wall = place_and_score(policy, records, jax.random.key(0))
            scores[name] = (success, chosen, wall)
            print(
                f"{row} {name}: "
                + ", ".join(f"{s} {success[splits == s].mean():.1%}" for s in DEV_SPLITS)
                + f", pooled {success.mean():.1%} ({wall:.1f} s)",
                flush=True,
            )
        k = choose_k({k: float(scores[f"joint@{k}"][0].mean()) for k in CANDIDATES})
        report[row] = {
            "k": k,
            "success": {
                name: {s: float(v[0][splits == s].mean()) for s in DEV_SPLITS} | {"pooled": float(v[0].mean())}
                for name, v in scores.items()
            },
            "fallbacks": {name: sum(d == "joint_fallback" for d in v[1]) for name, v in scores.items()},
            "wall_s": {name: v[2] for name, v in scores.items()},
            "test": becomes_default(scores[f"joint@{k}"][0], scores["argmax"][0], splits),
            "scenes": {name: v[0].astype(int).tolist() for name, v in scores.items()},
        }
        print(f"{row}: k = {k}; joint against argmax {report[row]['test']}", flush=True)
    report["ids"] = [record.id for record in records]
    args.out.write_text(json.dumps(report, indent=1) + "\n")


if __name__ == "__main__":
    main()
