"""Zero-shot measurements of a backbone on benchmark scenes (no adapters, nothing trained here).

Grounding: for every tuple of every scene, the prediction is the visual token (the N crops, then
the workspace image for the table) with the highest cosine similarity to the prompted reference
phrase (`PromptConfig.text_for`); top-1 accuracy against the ground-truth token.
Retrieval: every crop of the split against the prompted names of a pool of objects (the whole
library, and the split's own objects); top-1 and top-5 accuracy.
"""

from __future__ import annotations

import collections
import dataclasses
from pathlib import Path
from typing import Any

import numpy as np

from ocplace.models.backbone import Backbone, PromptConfig
from ocplace.sim.dataset.job import listed_scenes
from ocplace.sim.dataset.loader import CROP_SIZE, example_from_record


@dataclasses.dataclass
class _TextCache:
    backbone: Backbone
    cache: dict = dataclasses.field(default_factory=dict)

    def __call__(self, texts: list[str]) -> np.ndarray:
        missing = [t for t in dict.fromkeys(texts) if t not in self.cache]
        if missing:
            self.cache.update(zip(missing, self.backbone.encode_texts(missing), strict=True))
        return np.stack([self.cache[t] for t in texts])


def evaluate_split(
    backbone: Backbone,
    dataset_dir: str | Path,
    split: str,
    library,
    prompt: PromptConfig = PromptConfig(),
    limit: int | None = None,
    progress: bool = False,
) -> dict:
    """Grounding accuracy (overall, per level, table vs object tuples) and crop-to-name retrieval."""
    from ocplace.runtime.progress import progress_bar

    encode_texts = _TextCache(backbone)
    pools = {"library": library.names(), "split": None}
    counts: collections.Counter[tuple[str, str]] = collections.Counter()
    chance = []
    crop_features, crop_names = [], []
    scenes = listed_scenes(dataset_dir, split)[:limit]
    for scene in progress_bar(scenes, desc=f"eval {split}", unit="scene", enabled=progress):
        record = scene.read()
        example = example_from_record(record, CROP_SIZE)
        visual = backbone.encode_images(np.concatenate([example.crops, example.workspace[None]]))
        text = encode_texts([prompt.text_for(t) for t in example.texts])
        predictions = np.argmax(text @ visual.T, axis=1)
        level = record.level
        for prediction, target in zip(predictions, example.targets, strict=True):
            kind = "table" if target == len(example.crops) else "object"
            for group in ("all", f"level_{level}", f"{kind}_tuples"):
                counts[group, "tuples"] += 1
                counts[group, "correct"] += int(prediction == target)
            chance.append(1.0 / len(visual))
        names = {obj.object_id: obj.name for obj in record.objects}
        crop_features.append(visual[:-1])
        crop_names += [names[int(i)] for i in example.box_object_ids]
    pools["split"] = sorted(set(crop_names))
    grounding: dict[str, Any] = {
        group: counts[group, "correct"] / counts[group, "tuples"] for group, key in counts if key == "tuples"
    }
    grounding["tuples"] = counts["all", "tuples"]
    grounding["counts"] = {group: count for (group, key), count in counts.items() if key == "tuples"}
    grounding["scenes"] = len(scenes)
    grounding["chance"] = float(np.mean(chance))
    crops = np.concatenate(crop_features)
    retrieval = {
        name: _retrieval(crops, crop_names, pool, library, prompt, encode_texts) for name, pool in pools.items()
    }
    return {"grounding": grounding, "retrieval": retrieval}


def _retrieval(
    crops: np.ndarray, crop_names: list[str], pool: list[str], library, prompt: PromptConfig, encode_texts
) -> dict:
    texts = encode_texts([prompt.text_for(library.get(name).human_name) for name in pool])
    scores = crops @ texts.T
    truth = np.array([pool.index(name) for name in crop_names])
    rank = (scores > scores[np.arange(len(truth)), truth][:, None]).sum(axis=1)
    return {
        "pool_size": len(pool),
        "crops": len(truth),
        "top1": float(np.mean(rank == 0)),
        "top5": float(np.mean(rank < 5)),
        "chance_top1": 1.0 / len(pool),
    }


def format_report(report: dict) -> str:
    """A markdown table: grounding and retrieval per backbone and split."""
    lines = [
        "| backbone | split | grounding top-1 | object tuples | table tuples | chance | "
        "retrieval top-1 (library) | top-5 (library) | top-1 (split pool) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for name, splits in report["results"].items():
        for split, result in splits.items():
            g, r = result["grounding"], result["retrieval"]
            lines.append(
                f"| {name} | {split} | {g['all']:.1%} ({g['tuples']}) | {g.get('object_tuples', 0):.1%} | "
                f"{g.get('table_tuples', 0):.1%} | {g['chance']:.1%} | {r['library']['top1']:.1%} "
                f"(of {r['library']['pool_size']}) | {r['library']['top5']:.1%} | "
                f"{r['split']['top1']:.1%} (of {r['split']['pool_size']}) |"
            )
    return "\n".join(lines)
