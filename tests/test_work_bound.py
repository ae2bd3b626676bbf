"""perf/work_bound.py: the shortest wall a schedule of a one-worker run's tasks allows."""

import json
import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).parents[1] / "perf" / "work_bound.py"

# seconds; "train" and "prepare" are two CPUs wide in the default experiment, evaluations one
STEPS = {
    "backbone": 60,
    "prepare ours": 120,
    "train ours": 600,
    "train grids": 1200,
    "evaluate ours": 300,
    "evaluate grids": 900,
    "evaluate no_adapter": 300,
}


def bound(tmp_path: Path, cpus: int, recorded: bool = False) -> list[str]:
    """The script's lines for STEPS; `recorded`: each step records its CPUs, as results.json does now,
    with widths unlike the older rule's, so that only a file without them is read by that rule."""
    results = tmp_path / "results.json"
    steps = [{"name": name, "wall_s": wall, "detail": ""} for name, wall in STEPS.items()]
    if recorded:
        steps = [step | {"cpus": 1} for step in steps]
    results.write_text(json.dumps({"pipeline": {"steps": steps}}))
    command = [sys.executable, str(SCRIPT), str(results), "--experiment", "default", "--cpus", str(cpus)]
    done = subprocess.run([*command, "--graph-min", "70"], capture_output=True, text=True, check=True)
    return done.stdout.splitlines()


def test_work_counts_each_task_at_its_recorded_width(tmp_path):
    # every step records one CPU: work = 3480 s = 58.0 CPU-min, the one-worker wall; on 2 CPUs 29.0 min
    lines = bound(tmp_path, cpus=2, recorded=True)
    assert lines[0] == "7 tasks one after another: 58.0 min; work 58.0 CPU-min"
    assert "no schedule on 2 CPUs beats 36.0 min: at most 1.61x over one worker" in lines  # the chain bounds it
    assert not any("older rule" in line for line in lines)


def test_older_results_are_counted_by_the_older_rule_and_say_so(tmp_path):
    # work = 2 * (60 + 120 + 600 + 1200) + 300 + 900 + 300 = 5460 s = 91.0 CPU-min; on 2 CPUs 45.5 min
    lines = bound(tmp_path, cpus=2)
    assert "does not record each step's CPUs: counted by the older rule for --experiment default" in lines[0]
    assert lines[1] == "7 tasks one after another: 58.0 min; work 91.0 CPU-min"
    assert "no schedule on 2 CPUs beats 45.5 min: at most 1.27x over one worker" in lines
    assert lines[-1] == "the graph's 70.0 min is +53.8% over that bound"


def test_many_cpus_are_bounded_by_the_longest_chain(tmp_path):
    # backbone -> train grids -> evaluate grids = 2160 s; Ours' chain with its prepare is only 1080 s
    lines = bound(tmp_path, cpus=64)
    assert "the longest chain of tasks waiting on each other: 36.0 min (the bound on any number of CPUs)" in lines
    assert "no schedule on 64 CPUs beats 36.0 min: at most 1.61x over one worker" in lines


def test_bad_input_is_refused_with_a_message(tmp_path):
    not_reproduce = tmp_path / "other.json"
    not_reproduce.write_text(json.dumps({"evaluations": []}))
    broken = tmp_path / "broken.json"
    broken.write_text("{")
    for arguments, message in [
        ([str(not_reproduce)], "holds no reproduce steps"),
        ([str(broken)], "cannot read"),
        ([str(tmp_path / "missing.json")], "cannot read"),
        ([str(not_reproduce), "--cpus", "0"], "--cpus must be at least 1"),
    ]:
        done = subprocess.run([sys.executable, str(SCRIPT), *arguments], capture_output=True, text=True)
        assert done.returncode != 0 and message in done.stderr and "Traceback" not in done.stderr
