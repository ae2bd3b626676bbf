"""What Table I derives from the per-scene outcomes of a results JSON: a 95% interval for every cell, and
the selective table of the robot's refusal gate.

Table I scores the paper's protocol (every reference grounded at its argmax, the object always placed).
The policy a robot runs refuses a scene when a reference's best token is below the gate's threshold
(`ocplace.vocabulary.GATE_THRESHOLD`); the selective table reports, at that threshold, how many scenes
the gate lets through (coverage) and how many of those succeed, from each scene's `confidence`.

Both need every scene's outcome. `eval.results.summarise` stores them (`derived`) before it drops the
scenes, so a summary's tables are its full results' tables.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ocplace.errors import ResultsError
from ocplace.eval.harness import LEVEL_GROUPS
from ocplace.eval.intervals import success_interval
from ocplace.vocabulary import GATE_THRESHOLD

COLUMNS = (*LEVEL_GROUPS, "overall")  # Table I's columns per subset: each level, the object levels, all


def base_runs(results: Mapping[str, Any]) -> list[dict[str, Any]]:
    """Evaluations with the experiment's own seeds: every one unless `--seeds` or backbone seeds added repeats."""
    return [e for e in results["evaluations"] if e.get("seed") is None and e.get("backbone_seed") is None]


def full_runs(results: Mapping[str, Any]) -> list[dict[str, Any]]:
    """Evaluations of runs trained on the whole training set (Table I's rows), in results order."""
    return [e for e in base_runs(results) if e["fraction"] == 1.0]


def repeats(results: Mapping[str, Any], entry: Mapping[str, Any]) -> list[dict[str, Any]]:
    """`entry` and its repeats with other seeds: the same method and fraction."""
    return [e for e in results["evaluations"] if e["method"] == entry["method"] and e["fraction"] == entry["fraction"]]


def subset_scenes(entry: Mapping[str, Any], subset: str) -> list[dict[str, Any]]:
    """The per-scene outcomes of `entry` on `subset`; ResultsError when the results hold none (a summary)."""
    body = entry["subsets"].get(subset)
    if body is None:
        return []
    if body.get("omitted_scenes") or (not body["scenes"] and body["aggregate"]["overall"]["scenes"]):
        raise ResultsError(
            f"{entry['key']} on {subset}: these results hold no per-scene outcomes (a summary); intervals and the "
            "selective table need them: read the full results.json that `ocplace reproduce` or `ocplace evaluate` "
            "wrote (or the committed per-scene outcomes, docs/results/)"
        )
    scenes: list[dict[str, Any]] = body["scenes"]
    return scenes


def successes(runs: Sequence[Mapping[str, Any]], subset: str, column: str) -> np.ndarray:
    """`(runs, scenes)` success of the mode in `column`'s scenes of `subset` (`overall`: every scene); every
    run must hold the same scenes in the same order."""
    levels = LEVEL_GROUPS.get(column)
    rows, ids = [], None
    for entry in runs:
        scenes = [s for s in subset_scenes(entry, subset) if levels is None or s["level"] in levels]
        if ids is not None and [s["id"] for s in scenes] != ids:
            raise ResultsError(f"{entry['key']} on {subset} was scored on other scenes than its repeats")
        ids = [s["id"] for s in scenes]
        rows.append([bool(s["success"]) for s in scenes])
    return np.array(rows, bool).reshape(len(rows), -1)


def row_intervals(runs: Sequence[Mapping[str, Any]], subsets: Sequence[str]) -> dict[str, Any]:
    """`{subset: {column: [mean, low, high, runs, scenes]}}`; a column without scenes is left out."""
    intervals = {}
    for subset in subsets:
        cells = {}
        for column in COLUMNS:
            observed = successes(runs, subset, column)
            if observed.size:
                cells[column] = list(success_interval(observed))
        if cells:
            intervals[subset] = cells
    return intervals


def row_selective(runs: Sequence[Mapping[str, Any]], subsets: Sequence[str], threshold: float) -> dict[str, Any]:
    """`{subset: {coverage, success_when_placed, placed_success, scenes}}` at `threshold`, pooled over the
    runs; a subset where no scene reports a confidence (the method does not ground) is left out. A scene
    without one where others have it (nothing was grounded: the parse failed) is not placed."""
    selective = {}
    for subset in subsets:
        scenes = [scene for entry in runs for scene in subset_scenes(entry, subset)]
        confidences = [scene.get("confidence") for scene in scenes]
        if all(confidence is None for confidence in confidences):
            continue
        placed = np.array([confidence is not None and confidence >= threshold for confidence in confidences])
        succeeded = np.array([bool(scene["success"]) for scene in scenes])
        selective[subset] = {
            "coverage": float(placed.mean()),
            "success_when_placed": float(succeeded[placed].mean()) if placed.any() else None,
            "placed_success": float((succeeded & placed).mean()),  # Table I under the gate: a refusal fails
            "scenes": len(scenes),
        }
    return selective


def derive(results: Mapping[str, Any]) -> dict[str, Any]:
    """Intervals and the selective table of every Table I row (`full_runs`), keyed by the row's key."""
    threshold = results.get("gate_threshold", GATE_THRESHOLD)
    subsets = results["settings"]["subsets"]
    rows = {entry["key"]: repeats(results, entry) for entry in full_runs(results)}
    return {
        "gate_threshold": threshold,
        "intervals": {key: row_intervals(runs, subsets) for key, runs in rows.items()},
        "selective": {key: row_selective(runs, subsets, threshold) for key, runs in rows.items()},
    }


def derived(results: Mapping[str, Any]) -> dict[str, Any]:
    """The stored derivation of a summary, else `derive` (which needs the per-scene outcomes)."""
    return results.get("derived") or derive(results)
