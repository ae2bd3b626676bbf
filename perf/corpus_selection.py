"""Choosing the foundation backbone's settings on the corpus' validation split, never on a test subset.

Each candidate is the default recipe with one change, pretrained at a selection size (fewer scenes
and steps than the default, the same for every candidate) and scored by zero-shot grounding of the
held-out corpus categories (`ocplace backbone validate`; `train/pretrain/validation.py`). The random
initialisation of the same architecture is the floor.

Usage: `python perf/corpus_selection.py --dev DEV --out selection.json [--candidates base balanced ...]
[--scenes 200 --steps 200]`, DEV holding dev_seen and dev_colour; each candidate is also scored on their
object tuples, and rule C of docs/settings.md (written before the run) says which changes are kept.
Candidates:
    base          the default recipe
    frozen16      only the trunk's last block and head fine-tuned (16 frozen entries; default 13)
    frozen10      the last seven blocks and head fine-tuned (10 frozen entries)
    objects70     70% of each batch corpus models as rendered (default 50%), 15% recoloured, 15% primitives
    no-extras     corpus models only: no recoloured objects, no primitives
    balanced      within a kind, a category group first, then a class of it (`OptimConfig.balance`)
    colour-open   recoloured corpus objects keep colour-category captions ("a yellow bowl"; `colour_captions`)
    seen-captions the default without them (`colour_captions="seen"`)
    large         also the corpus' large tier: models over 40 cm (chairs, beds, cars), shrunk (`large_models`)
    cutouts       also Tux Paint's stamps as thin textured cut-outs (`cutouts`; `sim/corpus/stamps.py`)
    emoji         also Fluent Emoji 3-D as thin textured cut-outs (`cutouts`; `sim/corpus/emoji.py`)
    before        the recipe of the issue-40 record (13 frozen entries at 128 px, no colour-category captions)
                  with today's held-out categories: the reference reach is measured against
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
from ocplace.models.offline_recipes import PretrainConfig, default_config
from ocplace.sim.corpus.build import build_corpus
from ocplace.sim.library import load_library
from ocplace.train.pretrain.loop import pretrain
from ocplace.train.pretrain.validation import validation_scenes


def candidate_config(base: PretrainConfig, name: str) -> PretrainConfig:
    model, render, optim = base.model, base.render, base.optim
    if name == "frozen16":
        model = dataclasses.replace(model, frozen_blocks=16)
    elif name == "frozen10":
        model = dataclasses.replace(model, frozen_blocks=10)
    elif name == "objects70":
        optim = dataclasses.replace(optim, kind_shares=(("object", 0.7), ("recoloured", 0.15), ("primitive", 0.15)))
    elif name == "no-extras":
        render = dataclasses.replace(render, recolour_share=0.0, primitives_per_scene=0)
    elif name == "balanced":
        optim = dataclasses.replace(optim, balance="group")
    elif name == "colour-open":
        render = dataclasses.replace(render, colour_captions="open")
    elif name == "large":
        render = dataclasses.replace(render, large_models="shrink")
    elif name == "cutouts":
        render = dataclasses.replace(render, cutouts=("stamps",))
    elif name == "emoji":
        render = dataclasses.replace(render, cutouts=("emoji",))
    elif name == "seen-captions":
        render = dataclasses.replace(render, colour_captions="seen")
    elif name == "before":
        model = dataclasses.replace(model, image_size=128)
        render = dataclasses.replace(render, colour_captions="seen")
    elif name != "base":
        raise SystemExit(f"unknown candidate {name!r}; see the module docstring")
    return dataclasses.replace(base, recipe=f"selection-{name}", model=model, render=render, optim=optim)


def cutouts_of(candidates: list[str]) -> tuple[str, ...]:
    """The cut-out sources the candidates render (converted before any of them pretrains)."""
    return tuple(source for name, source in (("cutouts", "stamps"), ("emoji", "emoji")) if name in candidates)


def verdicts(report: dict) -> dict[str, str]:
    """Rule C (docs/settings.md): each candidate's change is kept when its reach beats the base's by more than
    one standard error of the difference and its `dev_seen` is at most one point below the base's."""
    base = report["candidates"]["base"]
    found = {}
    for name, row in report["candidates"].items():
        if name == "base":
            continue
        margin = row["reach"] - base["reach"]
        se = math.hypot(
            standard_error(row["reach"], row["reach_references"]),
            standard_error(base["reach"], base["reach_references"]),
        )
        keep = margin > se and row["dev_seen"] >= base["dev_seen"] - 0.01
        found[name] = f"{'kept' if keep else 'not kept'}: reach {100 * margin:+.1f} points (SE {100 * se:.1f}), " + (
            f"dev_seen {100 * (row['dev_seen'] - base['dev_seen']):+.1f}"
        )
    return found


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dev", type=Path, required=True, help="dataset folder holding dev_seen and dev_colour")
    parser.add_argument("--candidates", nargs="+", default=["base", "balanced", "colour-open"])
    parser.add_argument("--scenes", type=int, default=200)
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--work", type=Path, default=Path("out/corpus_selection"))
    parser.add_argument("--out", type=Path, default=Path("corpus_selection.json"))
    args = parser.parse_args()

    library, corpus = load_library(), build_corpus(progress=False, cutouts=cutouts_of(args.candidates))
    default = default_config()
    base = dataclasses.replace(
        default,
        render=dataclasses.replace(default.render, scenes=args.scenes),
        optim=dataclasses.replace(
            default.optim, steps=args.steps, warmup_steps=max(args.steps // 14, 1), checkpoint_every=args.steps
        ),
    )
    scenes = validation_scenes(library, corpus, default.render)
    report = {"scenes": args.scenes, "steps": args.steps, "cpu_count": os.cpu_count(), "candidates": {}}
    for name in args.candidates:
        config = candidate_config(base, name)
        began = time.perf_counter()
        result = pretrain(config, library, args.work / name, progress=True)
        row = {"pretrain_s": round(time.perf_counter() - began, 1)}
        row |= scores(result.backbone, scenes, args.dev, library)
        if "random_init" not in report:
            params = init_params(base.model, jax.random.key(0))
            floor = OfflineBackbone(base.model, params, result.backbone.text_tower, source="random init")
            report["random_init"] = scores(floor, scenes, args.dev, library)
            print("random init", json.dumps(report["random_init"]), flush=True)
        report["candidates"][name] = row
        print(name, json.dumps(row), flush=True)
        args.out.write_text(json.dumps(report, indent=2) + "\n")
    if "base" in report["candidates"]:
        report["verdicts"] = verdicts(report)
        print(json.dumps(report["verdicts"], indent=1))
        args.out.write_text(json.dumps(report, indent=2) + "\n")


if __name__ == "__main__":
    main()
