"""Choosing how much of the ImageNet trunk to fine-tune, and at what input size, on the dev splits and the
corpus' category-held-out validation: never on a test subset.

Each candidate is the default recipe (the furniture corpus, `open`) with another trunk depth or input
size, pretrained at a selection size (the same for all), then scored zero-shot (no adapters) on:
- reach: grounding top-1 of the corpus categories held out of pretraining (`ocplace backbone validate`);
- dev_colour: object-tuple grounding top-1 on the dev split of the seen colour variants;
- dev_seen: object-tuple grounding top-1 on the dev split of seen objects.
The rule (docs/settings.md, written before the run): among the candidates whose dev_seen is at least the
best dev_seen minus one point, take the highest reach + dev_colour; it replaces the current setting only
when it beats the current's by more than one standard error of that sum. The random initialisation of the
architecture is the floor.

Usage: `python perf/trunk_selection.py --dev DEV --out selection.json [--candidates 13@128 16@128 ...]`
where DEV holds dev_seen and dev_colour (`ocplace generate --out DEV --split dev_seen --dev 400`, then
`--split dev_colour`). A candidate is `FROZEN@SIZE`: the number of leading trunk entries (stem, blocks_00,
...) kept frozen, and the input size in pixels.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import time
from pathlib import Path

import jax
from selection_scores import scores, standard_error

import ocplace  # noqa: F401  (sets the headless OpenGL default before MuJoCo loads)
from ocplace.models.offline_backbone import OfflineBackbone, init_params
from ocplace.models.offline_recipes import default_config
from ocplace.sim.corpus.build import build_corpus
from ocplace.sim.library import load_library
from ocplace.train.pretrain.loop import pretrain
from ocplace.train.pretrain.validation import validation_scenes

CURRENT = "13@160"  # rule T chose it on 2026-12-04


def choose(rows: dict[str, dict], current: str = CURRENT) -> tuple[str, str]:
    """The rule of the module docstring: (chosen candidate, why)."""
    best_seen = max(row["dev_seen"] for row in rows.values())
    eligible = {name: row for name, row in rows.items() if row["dev_seen"] >= best_seen - 0.01}
    best = max(eligible, key=lambda name: eligible[name]["reach"] + eligible[name]["dev_colour"])
    if best == current or current not in rows:
        return best, "the highest reach + dev_colour among the eligible"
    ours, theirs = rows[current], rows[best]
    margin = (theirs["reach"] + theirs["dev_colour"]) - (ours["reach"] + ours["dev_colour"])
    se = math.sqrt(
        sum(
            standard_error(row["reach"], row["reach_references"]) ** 2
            + standard_error(row["dev_colour"], row["dev_colour_references"]) ** 2
            for row in (ours, theirs)
        )
    )
    if current in eligible and margin <= se:
        return current, f"{best} beats it by {100 * margin:.1f} points, not more than one SE ({100 * se:.1f})"
    return best, f"beats {current} by {100 * margin:.1f} points (one SE: {100 * se:.1f})"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dev", type=Path, required=True, help="dataset folder holding dev_seen and dev_colour")
    parser.add_argument("--candidates", nargs="+", default=["18@128", "16@128", "13@128", "10@128", "13@160"])
    parser.add_argument("--scenes", type=int, default=200)
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--work", type=Path, default=Path("out/trunk_selection"))
    parser.add_argument("--out", type=Path, default=Path("trunk_selection.json"))
    args = parser.parse_args()

    library, corpus = load_library(), build_corpus(progress=False)
    default = default_config()
    base = dataclasses.replace(
        default,
        recipe="selection",
        render=dataclasses.replace(default.render, scenes=args.scenes),
        optim=dataclasses.replace(
            default.optim, steps=args.steps, warmup_steps=max(args.steps // 14, 1), checkpoint_every=args.steps
        ),
    )
    scenes = validation_scenes(library, corpus, default.render)
    report = {"scenes": args.scenes, "steps": args.steps, "cpu_count": os.cpu_count(), "candidates": {}}
    for candidate in args.candidates:
        frozen, size = (int(part) for part in candidate.split("@"))
        config = dataclasses.replace(base, model=dataclasses.replace(base.model, frozen_blocks=frozen, image_size=size))
        began = time.perf_counter()
        result = pretrain(config, library, args.work / candidate, progress=True)
        row = {
            "pretrain_s": round(time.perf_counter() - began, 1),
            **scores(result.backbone, scenes, args.dev, library),
        }
        if "random_init" not in report:
            floor = OfflineBackbone(base.model, init_params(base.model, jax.random.key(0)), result.backbone.text_tower)
            report["random_init"] = scores(floor, scenes, args.dev, library)
            print("random init", json.dumps(report["random_init"]), flush=True)
        report["candidates"][candidate] = row
        print(candidate, json.dumps(row), flush=True)
        args.out.write_text(json.dumps(report, indent=2) + "\n")
    report["chosen"], report["why"] = choose(report["candidates"])
    print(f"chosen: {report['chosen']} ({report['why']})", flush=True)
    args.out.write_text(json.dumps(report, indent=2) + "\n")


if __name__ == "__main__":
    main()
