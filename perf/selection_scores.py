"""What the backbone selection scripts score a pretrained backbone on, zero-shot (no adapters): reach (the
corpus' held-out categories) and the object tuples of the dev splits. Never a test subset."""

from __future__ import annotations

import math
from pathlib import Path

from ocplace.train.pretrain.evaluate import evaluate_split
from ocplace.train.pretrain.validation import validation_grounding

DEV_SPLITS = ("dev_seen", "dev_colour")


def scores(backbone, scenes, dev: Path, library) -> dict:
    """Reach, dev_colour and dev_seen top-1 (object tuples) of one backbone, with their reference counts."""
    reach = validation_grounding(backbone, scenes)
    row = {"reach": reach["grounding_top1"], "reach_references": reach["references"]}
    for split in DEV_SPLITS:
        grounding = evaluate_split(backbone, dev, split, library)["grounding"]
        objects = grounding["object_tuples"]
        row[split] = objects
        row[f"{split}_references"] = grounding["counts"]["object_tuples"]
    return row


def standard_error(rate: float, count: int) -> float:
    """The binomial standard error of a rate observed on `count` references."""
    return math.sqrt(rate * (1 - rate) / max(count, 1))
