"""What the grounding knew, from the per-scene outcomes of an evaluation: every reference's probabilities over the
tokens, its true token and the chosen one (eval/harness.py records them), read back into per-reference rows.

From the rows: rank-1 and rank-2 accuracy per object and subset, what each object is taken for, and calibration
(the chosen token's probability against how often it is the true one). Pure NumPy over the outcomes file's lines
(`eval.results.outcome_lines`), so the grounding notebook's paper-scale section runs on the committed record.
"""

from __future__ import annotations

import collections
import dataclasses
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np


@dataclasses.dataclass(frozen=True)
class Reference:
    """One parsed reference of one scene-run whose true token is known."""

    method: str
    subset: str
    scene: str
    true_name: str  # the library object of the true token ("table" for the table)
    chosen_name: str  # the object of the token the method chose
    rank: int  # 1 + the tokens more probable than the true one
    chosen_probability: float
    true_probability: float

    @property
    def right(self) -> bool:
        return self.true_name == self.chosen_name


def references(lines: Iterable[Mapping[str, Any]], method: str | None = None) -> list[Reference]:
    """The references of the outcome lines (of `method` only, if given) that record probabilities and a true
    token; a reference whose parse matches no true tuple, or whose object has no box, is left out."""
    found = []
    for line in lines:
        if (method is not None and line.get("method") != method) or not line.get("probabilities"):
            continue
        names, chosen = line["token_names"], line.get("chosen_tokens") or [None] * len(line["probabilities"])
        for row, true, rank, token in zip(line["probabilities"], line["true_tokens"], line["true_ranks"], chosen):
            if true is None or token is None:
                continue
            found.append(
                Reference(
                    line["method"], line["subset"], line["id"], names[true], names[token], rank, row[token], row[true]
                )
            )
    return found


def accuracy_by_object(rows: Sequence[Reference]) -> dict[tuple[str, str], dict[str, float]]:
    """`{(subset, object): {"references", "rank1", "rank2", "chosen"}}`: how often the true token is the most probable,
    among the two most probable, and the chosen one (the joint decision may choose another than the most probable)."""
    groups: dict[tuple[str, str], list[Reference]] = collections.defaultdict(list)
    for row in rows:
        groups[row.subset, row.true_name].append(row)
    return {
        key: {
            "references": len(group),
            "rank1": float(np.mean([row.rank == 1 for row in group])),
            "rank2": float(np.mean([row.rank <= 2 for row in group])),
            "chosen": float(np.mean([row.right for row in group])),
        }
        for key, group in sorted(groups.items())
    }


def confusions(rows: Sequence[Reference]) -> collections.Counter[tuple[str, str]]:
    """How often each object (first) was grounded to each other one (second); right groundings left out."""
    return collections.Counter((row.true_name, row.chosen_name) for row in rows if not row.right)


def calibration(rows: Sequence[Reference], bins: int = 10) -> list[dict[str, float]]:
    """Per bin of the chosen token's probability: its mean, how often the choice is right, and the count (bins
    without references left out); and the expected calibration error over all of them as the last entry."""
    if not rows:
        return []
    confidence = np.array([row.chosen_probability for row in rows])
    right = np.array([row.right for row in rows], float)
    index = np.minimum((confidence * bins).astype(int), bins - 1)
    table = [
        {
            "low": b / bins,
            "high": (b + 1) / bins,
            "confidence": float(confidence[index == b].mean()),
            "accuracy": float(right[index == b].mean()),
            "references": int((index == b).sum()),
        }
        for b in range(bins)
        if (index == b).any()
    ]
    error = sum(cell["references"] * abs(cell["confidence"] - cell["accuracy"]) for cell in table) / len(rows)
    return [*table, {"expected_calibration_error": float(error)}]
