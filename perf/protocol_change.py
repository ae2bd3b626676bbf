"""What the paper's protocol changes in a Table I: the same runs scored always-placing, against the gated score.

A gated evaluation (before 2026-12-04: a scene refused when a reference's best token had P < 0.5, counted as
a failure) places exactly the scenes whose confidence passes the gate, at the same mode (the mode is the
sampler's most probable cell, not a sample), so it is recovered from an always-placing evaluation's
per-scene outcomes: success where the confidence passes, failure elsewhere. This script recovers it and
compares it with a results file scored under the gate (a summary will do), cell by cell, and prints both
protocols' overall success per row and subset.

Usage: `python perf/protocol_change.py --gated OLD.json --placed NEW.json [--threshold 0.5]`, NEW holding
per-scene outcomes with confidences (`results.json` of `ocplace reproduce` or `evaluate`).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from ocplace.eval.harness import LEVEL_GROUPS
from ocplace.eval.results import read_results
from ocplace.eval.statistics import subset_scenes

COLUMNS = (*LEVEL_GROUPS, "overall")


def gated_rates(entry: dict, subset: str, threshold: float) -> dict[str, float | None] | None:
    """Success per Table I column had `entry` refused below `threshold`; None for a method without confidences."""
    scenes = subset_scenes(entry, subset)
    if not scenes or all(scene.get("confidence") is None for scene in scenes):
        return None
    rates = {}
    for column in COLUMNS:
        levels = LEVEL_GROUPS.get(column)
        chosen = [s for s in scenes if levels is None or s["level"] in levels]
        placed = [s["success"] and s["confidence"] is not None and s["confidence"] >= threshold for s in chosen]
        rates[column] = sum(placed) / len(chosen) if chosen else None
    return rates


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--gated", type=Path, required=True, help="results scored under the gate (a summary will do)")
    parser.add_argument("--placed", type=Path, required=True, help="the same runs' results under the paper's protocol")
    parser.add_argument("--threshold", type=float, default=0.5, help="the gate the old results were scored with")
    args = parser.parse_args()

    gated, placed = read_results(args.gated), read_results(args.placed)
    old = {entry["key"]: entry for entry in gated["evaluations"]}
    report, cells, equal = [], 0, 0
    for entry in placed["evaluations"]:
        if entry["key"] not in old:
            continue
        for subset, body in entry["subsets"].items():
            before = old[entry["key"]]["subsets"].get(subset, {}).get("aggregate")
            if before is None:
                continue
            recovered = gated_rates(entry, subset, args.threshold)
            for column in ("table", "1obj", "2obj", "overall"):
                then = before[column]["success"]
                again = body["aggregate"][column]["success"] if recovered is None else recovered[column]
                cells += 1
                equal += abs(then - again) < 1e-9
            report.append(
                {
                    "key": entry["key"],
                    "subset": subset,
                    "gated": before["overall"]["success"],
                    "recovered": recovered["overall"] if recovered else body["aggregate"]["overall"]["success"],
                    "placed": body["aggregate"]["overall"]["success"],
                }
            )
    for row in report:
        print(
            f"{row['key']:>22} {row['subset']:>12}: gated {100 * row['gated']:6.2f}, recovered "
            f"{100 * row['recovered']:6.2f}, always placed {100 * row['placed']:6.2f}"
        )
    print(f"{equal} of {cells} cells (Table, 1 Obj, 2 Obj, Overall) recovered exactly")
    print(json.dumps({"cells": cells, "equal": equal}))


if __name__ == "__main__":
    main()
