"""Grounding accuracy (per tuple and per scene) and the JSON-lines metrics log of a run."""

from __future__ import annotations

import dataclasses
import json
import logging
from pathlib import Path

import numpy as np

from ocplace.errors import TrainingError
from ocplace.paths import write_text_atomic

log = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True)
class GroundingAccuracy:
    tuple_accuracy: float  # share of tuples whose reference is grounded to the right token
    scene_accuracy: float  # share of scenes with every tuple right
    num_tuples: int
    num_scenes: int

    def as_dict(self, prefix: str = "") -> dict:
        return {f"{prefix}{key}": value for key, value in dataclasses.asdict(self).items()}


def grounding_accuracy(predictions: np.ndarray, targets: np.ndarray, text_mask: np.ndarray) -> GroundingAccuracy:
    """predictions, targets, text_mask `(num_scenes, max_tuples)`; padded tuples are ignored."""
    predictions, targets, text_mask = (np.asarray(a) for a in (predictions, targets, text_mask))
    correct = (predictions == targets) & text_mask
    num_tuples = int(text_mask.sum())
    scenes = text_mask.any(axis=-1)
    scene_correct = np.all(correct | ~text_mask, axis=-1) & scenes
    num_scenes = int(scenes.sum())
    return GroundingAccuracy(
        float(correct.sum()) / max(num_tuples, 1),
        float(scene_correct.sum()) / max(num_scenes, 1),
        num_tuples,
        num_scenes,
    )


class MetricsLog:
    """Append-only `metrics.jsonl`: one JSON object per line, each with a `step`."""

    def __init__(self, path: Path):
        self.path = Path(path)

    def append(self, record: dict) -> None:
        with self.path.open("a") as handle:
            handle.write(json.dumps(record, sort_keys=True) + "\n")
            handle.flush()

    def records(self) -> list[dict]:
        """Every record; a torn last line (a crash mid-append) is dropped with a warning."""
        if not self.path.exists():
            return []
        lines = [(number, line) for number, line in enumerate(self.path.read_text().splitlines(), 1) if line.strip()]
        records = []
        for number, line in lines:
            try:
                records.append(json.loads(line))
            except ValueError as error:
                if number < lines[-1][0]:
                    raise TrainingError(
                        f"{self.path} line {number} is not JSON ({error}); delete that line, or "
                        "the run directory to start the run over"
                    ) from error
                log.warning("%s: dropped its torn last line (a crash while writing it): %r", self.path, line[:80])
        return records

    def truncate_after(self, step: int) -> None:
        """Drops records past `step`: what a resumed run will redo."""
        kept = [r for r in self.records() if r["step"] <= step]
        write_text_atomic(self.path, "".join(json.dumps(r, sort_keys=True) + "\n" for r in kept))


def evaluate_features(model, features) -> GroundingAccuracy:
    """Grounding accuracy of a `GroundingModel` on a `Features` set."""
    logits = model.logits(features.text, features.visual, features.visual_mask)
    return grounding_accuracy(np.argmax(logits, axis=-1), features.targets, features.text_mask)
