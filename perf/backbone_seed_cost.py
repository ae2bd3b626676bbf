"""What one extra backbone seed cost a `reproduce` run, against issue 42's budget: its training steps + 20 CPU-min.

    python perf/backbone_seed_cost.py OUT/results.json [--seed 1] [--budget 20]

The seed's tasks are its pretraining (`backbone seed S`) and every step of a run on it (`... ~backboneS`); each
task's work is its wall x the CPUs it held (results.json records both). The pretraining's own timings (its
backbone's `config.json`) split the steps' share from its set-up, renders and captions. Prints the seed's work,
the steps' part, the rest, and the rest against the budget.
"""

import argparse
import json
import re
from pathlib import Path


def seed_steps(results: dict, seed: int) -> list[dict]:
    """The `reproduce` steps of backbone seed `seed`: its pretraining and every task of a run on it."""
    runs_on_it = re.compile(rf"~backbone{seed}(\b|$)")
    return [
        step
        for step in results["pipeline"]["steps"]
        if step["name"] == f"backbone seed {seed}" or runs_on_it.search(step["name"])
    ]


def pretraining_timings(results: dict, seed: int) -> dict:
    """The pretraining's timings (seconds: setup, render, captions, train, total) of backbone seed `seed`."""
    spec = next(entry["backbone"] for entry in results["evaluations"] if entry.get("backbone_seed") == seed)
    config = json.loads((Path(spec.removeprefix("offline:")) / "config.json").read_text())
    return config["pretraining"]["timings_s"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("results", type=Path, help="results.json of a run with --backbone-seeds 2 or more")
    parser.add_argument("--seed", type=int, default=1, help="the backbone seed to cost (1: the first repeat)")
    parser.add_argument("--budget", type=float, default=20.0, help="CPU-minutes allowed beyond the steps")
    args = parser.parse_args()
    try:
        results = json.loads(args.results.read_text())
        steps = seed_steps(results, args.seed)
        pretraining = next(step for step in steps if step["name"] == f"backbone seed {args.seed}")
        timings = pretraining_timings(results, args.seed)
    except (OSError, ValueError, KeyError, StopIteration) as error:
        parser.error(
            f"{args.results}: no pretraining of backbone seed {args.seed} with its runs and backbone to read "
            f"({type(error).__name__}: {error}); give the results.json of a `reproduce --backbone-seeds` run"
        )
    work = sum(step["wall_s"] * step["cpus"] for step in steps) / 60
    training = timings["train_s"] * pretraining["cpus"] / 60
    for step in steps:
        print(f"  {step['name']:<45} {step['wall_s']:8.1f} s x {step['cpus']} CPUs")
    print(f"pretraining of seed {args.seed}: " + ", ".join(f"{k} {v:.1f}" for k, v in timings.items()) + " (s)")
    print(f"backbone seed {args.seed}: work {work:.1f} CPU-min, of which its training steps {training:.1f}")
    rest = work - training
    verdict = "met" if rest <= args.budget else "missed"
    print(f"beyond the steps: {rest:.1f} CPU-min against a budget of {args.budget:.0f} ({verdict})")


if __name__ == "__main__":
    main()
