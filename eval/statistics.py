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

from ocplace import serial
from ocplace.errors import ResultsError
from ocplace.eval.harness import LEVEL_GROUPS
from ocplace.eval.intervals import paired_interval, success_interval
from ocplace.vocabulary import GATE_THRESHOLD

COLUMNS = (*LEVEL_GROUPS, "overall")  # Table I's columns per subset: each level, the object levels, all


def base_runs(results: Mapping[str, Any]) -> list[dict[str, Any]]:
    """Evaluations with the experiment's own seeds: every one unless `--seeds` or backbone seeds added repeats."""
    return [e for e in results["evaluations"] if e.get("seed") is None and e.get("backbone_seed") is None]


def full_runs(results: Mapping[str, Any]) -> list[dict[str, Any]]:
    """Evaluations of runs trained on the whole training set (Table I's rows), in results order."""
    return [e for e in base_runs(results) if e["fraction"] == 1.0]


def repeats(results: Mapping[str, Any], entry: Mapping[str, Any]) -> list[dict[str, Any]]:
    """`entry` and its repeats with other seeds: the same method and fraction, one per distinct model.

    A row that learns nothing (w/o Adapter) is repeated with every adapter seed of the rows beside it, but its
    model is the same on one backbone and its mode does not depend on the evaluation's seed: runs of one row on the
    same backbone with the same description and the same outcomes count once (the first), so such a row is one run
    per backbone, not nine."""
    kept, seen = [], set()
    for e in results["evaluations"]:
        if e["method"] != entry["method"] or e["fraction"] != entry["fraction"]:
            continue
        model = (e.get("backbone_seed"), serial.to_json(e.get("description")), serial.to_json(_outcomes(e)))
        if model not in seen:
            seen.add(model)
            kept.append(e)
    return kept


def _outcomes(entry: Mapping[str, Any]) -> dict[str, Any]:
    """What an evaluation's outcomes are, compared between its repeats: per subset each scene's success (none in a
    summary) and the overall rate."""
    return {
        subset: ([scene["success"] for scene in body["scenes"]], body["aggregate"]["overall"].get("success"))
        for subset, body in entry["subsets"].items()
    }


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


def pairs(runs: Sequence[Mapping[str, Any]], reference: Sequence[Mapping[str, Any]]) -> list[tuple[Any, Any]]:
    """(run, reference run) on the same scenes and backbone: each reference run with the run of the same seeds, else
    with the row's one run on its backbone (a row counted once per backbone, `repeats`); unmatched runs are left out."""
    by_seeds = {(r.get("seed"), r.get("backbone_seed")): r for r in runs}
    by_backbone: dict[Any, list[Mapping[str, Any]]] = {}
    for r in runs:
        by_backbone.setdefault(r.get("backbone_seed"), []).append(r)
    matched = []
    for ref in reference:
        run = by_seeds.get((ref.get("seed"), ref.get("backbone_seed")))
        alone = by_backbone.get(ref.get("backbone_seed"), [])
        run = run if run is not None else alone[0] if len(alone) == 1 else None
        if run is not None:
            matched.append((run, ref))
    return matched


def paired_differences(
    runs: Sequence[Mapping[str, Any]], reference: Sequence[Mapping[str, Any]], subsets: Sequence[str]
) -> dict[str, Any]:
    """`{subset: {column: [mean, low, high, units, scenes]}}` of a row's success minus the reference row's, paired on
    the same scenes and runs (`pairs`). The bootstrap's units are the backbones when there are several (a backbone's
    pairs averaged per scene: runs on one backbone are not independent), else the pairs."""
    matched = pairs(runs, reference)
    if not matched:
        return {}
    backbones = [ref.get("backbone_seed") for _, ref in matched]
    table = {}
    for subset in subsets:
        cells = {}
        for column in COLUMNS:
            differences = np.stack(
                [
                    successes([run], subset, column)[0].astype(float) - successes([ref], subset, column)[0]
                    for run, ref in matched
                ]
            )
            if not differences.size:
                continue
            if len(set(backbones)) > 1:
                differences = np.stack(
                    [differences[[b == unit for b in backbones]].mean(axis=0) for unit in dict.fromkeys(backbones)]
                )
            cells[column] = list(paired_interval(differences))
        if cells:
            table[subset] = cells
    return table


REFERENCE_ROW = "ours"  # the row the paired table compares every other row with


def derive(results: Mapping[str, Any]) -> dict[str, Any]:
    """Intervals, the selective table and the paired differences against Ours of every Table I row (`full_runs`),
    keyed by the row's key."""
    threshold = results.get("gate_threshold", GATE_THRESHOLD)
    subsets = results["settings"]["subsets"]
    rows = {entry["key"]: repeats(results, entry) for entry in full_runs(results)}
    reference = rows.get(REFERENCE_ROW)
    return {
        "gate_threshold": threshold,
        "intervals": {key: row_intervals(runs, subsets) for key, runs in rows.items()},
        "selective": {key: row_selective(runs, subsets, threshold) for key, runs in rows.items()},
        "paired": {
            key: paired_differences(runs, reference, subsets)
            for key, runs in rows.items()
            if reference is not None and key != REFERENCE_ROW
        },
    }


def derived(results: Mapping[str, Any]) -> dict[str, Any]:
    """The stored derivation of a summary, else `derive` (which needs the per-scene outcomes)."""
    return results.get("derived") or derive(results)
