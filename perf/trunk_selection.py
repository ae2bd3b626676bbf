"""Choosing how much of the ImageNet trunk to fine-tune, and at what input size, on seen objects only.

Every fifth training object (6 of 30) is held out of pretraining: a development split made of
seen objects, so no unseen object, table texture or instruction is looked at. Each candidate is
pretrained on the other 24 objects at a fixed selection size (150 scenes x 2 renders,
150 steps of 64: the demo recipe's size when the trunk was chosen), then measured on the `seen` test
subset's tuples whose reference is a held-out object: zero-shot grounding top-1 among the
scene's visual tokens, and crop-to-name retrieval among the 30 training names.

Usage: `python perf/trunk_selection.py --dataset DIR --out selection.json [--candidates 13@128 16@128]`
where DIR holds a `seen` subset (`ocplace generate --out DIR --split seen`) and a candidate is
`FROZEN@SIZE`: the number of leading trunk entries (stem, blocks_00, ...) kept frozen, and the
input size in pixels.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import time
from pathlib import Path

import numpy as np

import ocplace  # noqa: F401  (sets the headless OpenGL default before MuJoCo loads)
from ocplace.models.backbone import PromptConfig
from ocplace.models.offline_recipes import recipe_config
from ocplace.sim.dataset.job import listed_scenes
from ocplace.sim.dataset.loader import CROP_SIZE, example_from_record
from ocplace.sim.library import load_library
from ocplace.train.pretrain.loop import pretrain

HOLDOUT_SPLIT = "development"


def development_library(library):
    """The library with every fifth training object moved to a split pretraining never renders."""
    seen = library.names("seen")
    held_out = set(seen[::5])
    objects = {
        name: dataclasses.replace(asset, split=HOLDOUT_SPLIT) if name in held_out else asset
        for name, asset in library.objects.items()
    }
    return dataclasses.replace(library, objects=objects), sorted(held_out)


def measure(backbone, data: Path, held_out: list[str], seen_names: list[str], library, limit: int | None) -> dict:
    """Grounding on tuples that refer to a held-out object; retrieval of held-out crops among seen names."""
    prompt = PromptConfig()
    names = backbone.encode_texts([prompt.text_for(library.get(n).human_name) for n in seen_names])
    correct = tuples = 0
    ranks = []
    for scene in listed_scenes(data, "seen")[:limit]:
        record = scene.read()
        example = example_from_record(record, CROP_SIZE)
        object_names = {o.object_id: o.name for o in record.objects}
        crop_names = [object_names[int(i)] for i in example.box_object_ids]
        wanted = [
            k for k, target in enumerate(example.targets) if target < len(crop_names) and crop_names[target] in held_out
        ]
        crops_wanted = [k for k, name in enumerate(crop_names) if name in held_out]
        if not wanted and not crops_wanted:
            continue
        visual = backbone.encode_images(np.concatenate([example.crops, example.workspace[None]]))
        if wanted:
            texts = backbone.encode_texts([prompt.text_for(example.texts[k]) for k in wanted])
            predictions = np.argmax(texts @ visual.T, axis=1)
            correct += int(np.sum(predictions == np.asarray(example.targets)[wanted]))
            tuples += len(wanted)
        for k in crops_wanted:
            scores = names @ visual[k]
            ranks.append(int(np.sum(scores > scores[seen_names.index(crop_names[k])])))
    ranks = np.asarray(ranks)
    return {
        "grounding_top1": correct / max(tuples, 1),
        "tuples": tuples,
        "retrieval_top1": float(np.mean(ranks == 0)),
        "retrieval_top5": float(np.mean(ranks < 5)),
        "crops": len(ranks),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", type=Path, required=True)
    parser.add_argument("--candidates", nargs="+", default=["18@128", "16@128", "13@128", "10@128", "13@160"])
    parser.add_argument("--work", type=Path, default=Path("out/trunk_selection"))
    parser.add_argument("--limit", type=int)
    parser.add_argument("--out", type=Path, default=Path("trunk_selection.json"))
    args = parser.parse_args()

    library = load_library()
    dev_library, held_out = development_library(library)
    demo = recipe_config("demo")
    # The size the published selection ran at (the demo recipe has since shrunk to fit `make demo`), on
    # the training objects: the `task` pool, which the trunk was chosen for before the corpus existed.
    base = dataclasses.replace(
        demo,
        recipe="selection",
        render=dataclasses.replace(demo.render, pool="task", scenes=150),
        optim=dataclasses.replace(demo.optim, steps=150, warmup_steps=15, checkpoint_every=50),
    )
    report = {"held_out": held_out, "recipe": "selection", "cpu_count": os.cpu_count(), "candidates": {}}
    for candidate in args.candidates:
        frozen, size = (int(part) for part in candidate.split("@"))
        config = dataclasses.replace(base, model=dataclasses.replace(base.model, frozen_blocks=frozen, image_size=size))
        began = time.perf_counter()
        result = pretrain(config, dev_library, args.work / candidate, progress=True)
        row = {
            "pretrain_s": round(time.perf_counter() - began, 1),
            **measure(result.backbone, args.dataset, held_out, library.names("seen"), library, args.limit),
        }
        report["candidates"][candidate] = row
        print(candidate, json.dumps(row), flush=True)
        args.out.write_text(json.dumps(report, indent=2) + "\n")


if __name__ == "__main__":
    main()
