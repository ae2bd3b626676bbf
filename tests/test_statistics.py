"""Table I's intervals and the selective table of the refusal gate (eval/intervals.py, eval/statistics.py)."""

import copy

import numpy as np
import pytest
from scipy.stats import binomtest

from ocplace.errors import ResultsError
from ocplace.eval import results, statistics, table
from ocplace.eval.intervals import success_interval, wilson


@pytest.mark.parametrize("successes,scenes", [(0, 90), (37, 90), (160, 400), (400, 400)])
def test_wilson_matches_scipy(successes, scenes):
    expected = binomtest(successes, scenes).proportion_ci(0.95, method="wilson")
    assert wilson(successes / scenes, scenes) == pytest.approx((expected.low, expected.high), abs=1e-9)


def test_interval_of_one_run_is_about_the_binomial_one():
    rng = np.random.default_rng(1)
    observed = rng.random((1, 400)) < 0.4
    interval = success_interval(observed)
    low, high = wilson(observed.mean(), 400)
    assert interval.mean == observed.mean() and interval.runs == 1 and interval.scenes == 400
    assert interval.low <= low and interval.high >= high  # never narrower than Wilson's
    assert interval.high - interval.low == pytest.approx(high - low, rel=0.15)  # ~2 x 1.96 x 2.4 points


def test_interval_holds_every_success_and_failure_case():
    assert success_interval(np.ones((3, 90), bool))[1:3] == pytest.approx(wilson(1.0, 90))
    assert success_interval(np.zeros((1, 90), bool))[1:3] == pytest.approx(wilson(0.0, 90))


def test_seeds_that_disagree_widen_the_interval():
    rng = np.random.default_rng(2)
    agreeing = np.repeat(rng.random((1, 400)) < 0.5, 3, axis=0)
    disagreeing = np.stack([rng.random(400) < p for p in (0.3, 0.5, 0.7)])
    narrow, wide = success_interval(agreeing), success_interval(disagreeing)
    assert narrow[1:3] == pytest.approx(success_interval(agreeing[:1])[1:3])  # copies of one run add nothing
    assert wide.high - wide.low > 2 * (narrow.high - narrow.low)
    assert wide.low < 0.4 and wide.high > 0.6


def test_interval_is_deterministic_and_refuses_no_scene():
    observed = np.random.default_rng(3).random((2, 50)) < 0.6
    assert success_interval(observed) == success_interval(observed)
    with pytest.raises(ValueError, match="at least one"):
        success_interval(np.zeros((1, 0), bool))


def _results(scene_sets):
    """A results dict with one row (`ours`) and one repeat per scene set: each a list of (level, success, conf)."""
    entries = []
    for index, scenes in enumerate(scene_sets):
        rows = [
            {"id": f"seen-{k:05d}", "level": level, "success": ok, "confidence": confidence}
            for k, (level, ok, confidence) in enumerate(scenes)
        ]
        entries.append(
            {
                "key": "ours" if index == 0 else f"ours~seed{index}",
                "method": "ours",
                "label": "Ours",
                "fraction": 1.0,
                "description": {"adapters": f"run {index}"},  # each repeat its own model, as real results say
                "subsets": {"seen": {"aggregate": {"overall": {"scenes": len(rows)}}, "scenes": rows}},
            }
            | ({} if index == 0 else {"seed": index})
        )
    return {"settings": {"subsets": ["seen"]}, "gate_threshold": 0.5, "evaluations": entries}


def test_selective_table_counts_scenes_the_gate_lets_through():
    scenes = [("table", True, 1.0), ("1obj", True, 0.9), ("1obj", False, 0.2), ("2obj", True, 0.4)]
    found = statistics.derive(_results([scenes, scenes]))
    cell = found["selective"]["ours"]["seen"]
    assert cell == {"coverage": 0.5, "success_when_placed": 1.0, "placed_success": 0.5, "scenes": 8}
    objects = found["intervals"]["ours"]["seen"]["objects"]
    assert objects[0] == pytest.approx(2 / 3) and objects[3:] == [2, 3]  # 2 runs, the 3 object scenes


def test_a_method_without_confidence_has_no_selective_row():
    scenes = [("table", True, None), ("1obj", False, None)]
    assert statistics.derive(_results([scenes]))["selective"]["ours"] == {}
    unparsed = [("table", True, 0.9), ("1obj", False, None)]  # nothing grounded: the gate lets nothing through
    assert statistics.derive(_results([unparsed]))["selective"]["ours"]["seen"]["coverage"] == 0.5


def test_repeats_on_other_scenes_are_refused():
    first = [("table", True, 1.0), ("1obj", True, 0.9)]
    broken = _results([first, first])
    broken["evaluations"][1]["subsets"]["seen"]["scenes"][1]["id"] = "seen-00099"
    with pytest.raises(ResultsError, match="other scenes"):
        statistics.derive(broken)


def test_intervals_need_per_scene_outcomes_and_a_summary_keeps_them():
    full = _results([[("table", True, 1.0), ("1obj", False, 0.3), ("2obj", True, 0.8)]])
    full["dataset"], full["environment"] = {"dataset_hash": "x", "dir": "d"}, {"git": {}}
    full["settings"] |= {"backbone": "b", "parser": "offline", "num_samples": 1, "seed": 0}
    summary = results.summarise({**full, "evaluations": [_with_aggregates(entry) for entry in full["evaluations"]]})
    assert summary["derived"] == statistics.derive(full)
    assert table.interval_table(summary) == table.interval_table(full)
    bare = copy.deepcopy(summary)
    del bare["derived"]
    with pytest.raises(ResultsError, match="no per-scene outcomes"):
        statistics.derive(bare)
    assert "not available" in table.interval_table(bare)


def _with_aggregates(entry):
    from ocplace import serial
    from ocplace.eval.harness import SceneOutcome, aggregate_subset

    def outcome(scene):
        return SceneOutcome(
            scene["id"],
            scene["level"],
            scene["success"],
            float(scene["success"]),
            None,
            0,
            None,
            None,
            None,
            None,
            None,
            None,
            None,
            confidence=scene["confidence"],
        )

    body = entry["subsets"]["seen"]
    outcomes = [outcome(scene) for scene in body["scenes"]]
    scenes = [serial.to_dict(o) for o in outcomes]
    return {**entry, "subsets": {"seen": {"aggregate": aggregate_subset(outcomes), "scenes": scenes}}}
