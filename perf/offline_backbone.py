"""Offline backbone: pretraining time of a recipe, then zero-shot grounding and retrieval.

Runs (or resumes) `ocplace backbone pretrain --recipe R`, then measures, in the same run, the
pretrained backbone and the same architecture at random initialisation on the corpus' validation
split (`ocplace backbone validate`, under the default recipe's held-out names, so that every recipe
is scored on the same scenes) and on benchmark test splits (`ocplace backbone eval`). Writes a JSON
report with the timings and the machine's load average, which matters: the 30-minute budget is for 2
otherwise idle cores.

Usage: `python perf/offline_backbone.py --dataset DIR [--recipe default|strict|task|demo] [--variant
chosen] [--splits seen unseen_obj unseen_cat] [--out report.json]`. `--variant` changes the recipe
for comparisons: `vit` is the first offline backbone (a ViT from scratch, no attribute data), `no-
attributes` the chosen trunk without recoloured objects and primitives, `chosen` the recipe as it
is. The dataset comes from `ocplace generate --out DIR --split seen` (and `--split unseen_obj`,
`--split unseen_cat`).
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
import os
import time
from pathlib import Path

import jax

import ocplace  # noqa: F401  (sets the headless OpenGL default before MuJoCo loads)
from ocplace.models.offline_backbone import OfflineBackbone, init_params
from ocplace.models.offline_config import vit_config
from ocplace.models.offline_recipes import RECIPES, default_config, recipe_config
from ocplace.sim.corpus.build import build_corpus
from ocplace.sim.library import load_library
from ocplace.train.pretrain.evaluate import evaluate_split, format_report
from ocplace.train.pretrain.loop import pretrain
from ocplace.train.pretrain.validation import validation_grounding, validation_scenes


def variant_config(config, variant: str):
    """The recipe `config` changed as `variant` says (see the module docstring)."""
    no_attributes = dataclasses.replace(config.render, recolour_share=0.0, primitives_per_scene=0)
    if variant == "vit":
        return dataclasses.replace(config, model=vit_config(), render=no_attributes)
    if variant == "no-attributes":
        return dataclasses.replace(config, render=no_attributes)
    return config


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", type=Path, required=True)
    parser.add_argument("--recipe", default="default", choices=tuple(RECIPES))
    parser.add_argument("--variant", default="chosen", choices=("chosen", "no-attributes", "vit"))
    parser.add_argument("--backbone-dir", type=Path, help="pretrain into this directory (default: the cache)")
    parser.add_argument("--splits", nargs="+", default=["seen", "unseen_obj", "unseen_cat"])
    parser.add_argument("--limit", type=int)
    parser.add_argument("--out", type=Path, default=Path("offline_backbone_report.json"))
    args = parser.parse_args()

    library = load_library()
    config = variant_config(recipe_config(args.recipe), args.variant)
    report = {
        "recipe": args.recipe,
        "variant": args.variant,
        "key": config.key(),
        "cpu_count": os.cpu_count(),
        "started": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
        "load_average_before": os.getloadavg(),
    }
    began = time.perf_counter()
    result = pretrain(config, library, args.backbone_dir, progress=True)
    report["pretrain_wall_s"] = round(time.perf_counter() - began, 1)
    saved = json.loads((result.directory / "config.json").read_text())["pretraining"]
    report["pretrain_timings_s"] = saved["timings_s"]  # of the run that built it (maybe an earlier one)
    report["pretrain_resumed"] = saved["resumed"]
    report["load_average_after_pretrain"] = os.getloadavg()
    report["probe_loss"] = [result.probe_loss_before, result.probe_loss_after]
    report["fingerprint"] = result.backbone.fingerprint

    backbone = result.backbone
    random_init = OfflineBackbone(
        backbone.config, init_params(backbone.config, jax.random.key(0)), backbone.text_tower, source="random init"
    )
    report["results"] = {}
    scenes = validation_scenes(library, build_corpus(progress=False), default_config().render)
    report["validation"] = {
        name: validation_grounding(candidate, scenes)
        for name, candidate in (("pretrained", backbone), ("random_init", random_init))
    }
    for name, candidate in (("pretrained", backbone), ("random_init", random_init)):
        report["results"][name] = {
            split: evaluate_split(candidate, args.dataset, split, library, limit=args.limit, progress=True)
            for split in args.splits
        }
    report["load_average_end"] = os.getloadavg()
    args.out.write_text(json.dumps(report, indent=2) + "\n")
    print(format_report(report))
    for name, score in report["validation"].items():
        print(
            f"validation ({name}): grounding top-1 {score['grounding_top1']:.1%}, "
            f"retrieval {score['retrieval_top1']:.1%}"
        )
    print(
        f"pretraining ({args.recipe}): {report['pretrain_timings_s']} (load average before "
        f"{report['load_average_before'][0]:.1f}); wrote {args.out}"
    )


if __name__ == "__main__":
    main()
