"""The shortest wall time any scheduler could give a `reproduce` run on N CPUs, from its tasks' walls.

    python perf/work_bound.py ONE_WORKER/results.json --experiment default [--cpus 2] [--graph-min 123.2]

Each task of the graph declares its CPUs and keeps that width on every executor, because the width
decides JAX's last bits (docs/distributed.md); results.json records them per step (`cpus`). An older
results.json without them is read by the rule its version used (pretraining and training the
`--experiment`'s `cpus`, the rest one), and the script says so. So the work is fixed at
sum(wall x CPUs) over the tasks of a one-worker run,
and no schedule on N CPUs finishes sooner than work / N, nor sooner than its longest chain of tasks
that wait on each other (backbone -> shared features -> training -> evaluation). Prints the work in
CPU-minutes, that bound, the largest speed-up over the one-worker run it allows and, given the
graph's measured wall, how close the graph came to it.
"""

import argparse
import json
from pathlib import Path

from ocplace.configs import EXPERIMENTS, get


def older_task_cpus(name: str, cpus) -> int:
    """The CPUs the task `name` held in a results.json that does not record them (versions before
    `Step.cpus`), by the rule of experiments/pipeline.py's task_graph then, given the experiment's `cpus`."""
    if name == "backbone":
        return cpus.pretrain
    return cpus.train if name.startswith(("train ", "prepare ")) else 1


def longest_chain(walls: dict[str, float]) -> float:
    """Seconds of the longest backbone -> prepare -> train -> evaluate chain among `walls` (task name -> s)."""
    prepares = {name: name.removeprefix("prepare ").split("+") for name in walls if name.startswith("prepare ")}
    chains = []
    for name in walls:
        if name.startswith("evaluate "):
            run = name.removeprefix("evaluate ")
            method = run.split("@")[0]
            before = [walls[key] for key, methods in prepares.items() if method in methods]
            chains.append(walls.get("backbone", 0) + sum(before) + walls.get(f"train {run}", 0) + walls[name])
    return max(chains, default=0.0)


def pipeline_steps(results: Path) -> list[dict]:
    """The `reproduce` steps of a results.json (name and wall_s each); [] for a file without them."""
    try:
        steps = json.loads(results.read_text()).get("pipeline", {}).get("steps", [])
    except (OSError, ValueError, AttributeError) as error:
        raise SystemExit(f"cannot read {results}: {error}") from None
    return [step for step in steps if isinstance(step, dict) and {"name", "wall_s"} <= step.keys()]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("results", type=Path, help="results.json of a one-worker run (tasks one after another)")
    parser.add_argument(
        "--experiment",
        default="default",
        choices=list(EXPERIMENTS),
        help="for a results.json that does not record its steps' CPUs: the experiment whose task widths it used",
    )
    parser.add_argument("--cpus", type=int, default=2, help="the machine the bound is for")
    parser.add_argument("--graph-min", type=float, help="the graph's measured wall on those CPUs, in minutes")
    args = parser.parse_args()
    if args.cpus < 1:
        parser.error(f"--cpus must be at least 1, got {args.cpus}")
    steps = pipeline_steps(args.results)
    if not steps:
        parser.error(f"{args.results} holds no reproduce steps: give the results.json of an `ocplace reproduce` run")
    one_worker = sum(step["wall_s"] for step in steps) / 60
    if all("cpus" in step for step in steps):
        widths = [step["cpus"] for step in steps]
    else:
        rule = f"counted by the older rule for --experiment {args.experiment}"
        print(f"{args.results} does not record each step's CPUs: {rule}")
        widths = [older_task_cpus(step["name"], get(args.experiment).cpus) for step in steps]
    work = sum(step["wall_s"] * width for step, width in zip(steps, widths, strict=True)) / 60
    chain = longest_chain({step["name"]: step["wall_s"] for step in steps}) / 60
    bound = max(work / args.cpus, chain)
    print(f"{len(steps)} tasks one after another: {one_worker:.1f} min; work {work:.1f} CPU-min")
    print(f"the longest chain of tasks waiting on each other: {chain:.1f} min (the bound on any number of CPUs)")
    print(f"no schedule on {args.cpus} CPUs beats {bound:.1f} min: at most {one_worker / bound:.2f}x over one worker")
    if args.graph_min:
        print(f"the graph's {args.graph_min:.1f} min is {100 * (args.graph_min / bound - 1):+.1f}% over that bound")


if __name__ == "__main__":
    main()
