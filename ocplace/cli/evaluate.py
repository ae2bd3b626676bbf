"""CLI: `ocplace evaluate`: Table I from trained runs, or a re-run of a results JSON."""

from __future__ import annotations

import argparse
import os
import shutil
import sys
from pathlib import Path

from ocplace.cli.executor_options import add_executor_arguments, executor_config
from ocplace.cli.options import (
    MAX_CHUNK,
    MAX_SCENES,
    MAX_SEED,
    DeprecatedAlias,
    add_dataset_argument,
    config_from_arguments,
    count,
    number,
    seconds,
)
from ocplace.vocabulary import EXPERIMENT_NAMES, MAX_SAMPLES, SCENE_TIMEOUT_S, SCORED_SPLITS, TEST_SUBSETS

# `ocplace evaluate` options named after EvalSettings fields: left out (None), they keep its defaults.
# Written by hand, not generated: EvalSettings sits behind NumPy, too slow to import for `--help`.
EVAL_SETTINGS_OPTIONS = (
    "backbone",
    "experiment",
    "parser",
    "num_samples",
    "limit",
    "seed",
    "chunk_size",
    "threshold",
)


def register(subparsers: argparse._SubParsersAction) -> None:
    evaluate = subparsers.add_parser(
        "evaluate",
        help="score methods on the test subsets: results JSON + Table I markdown",
        description="Runs each method on the test subsets (the paper's seen, unseen_obj, unseen_inst, and our "
        "unseen_cat) of a dataset and "
        "scores it with the benchmark's success metric (mode and mean over samples), the "
        "physical drop check on the first K scenes per subset, and parse and grounding "
        "accuracy. Writes RESULTS.json and RESULTS.md (the tables) and prints the tables. "
        "With --rerun, evaluates again from a results JSON and lists every difference.",
    )
    add_dataset_argument(evaluate, "dataset folder (`ocplace generate`)")
    evaluate.add_argument(
        "--methods",
        help="comma-separated method names, or `all` (every registered method; the default without --policy)",
    )
    evaluate.add_argument(
        "--policy",
        action="append",
        default=[],
        metavar="MODULE:CALLABLE|DIR",
        help="also evaluate your own policy: a Method, or a callable place(observation) -> (x, y) that gets the "
        "Gymnasium environment's observation (docs/evaluation.md), or a policy folder (`ocplace export`, "
        "out/demo/policy); repeatable; the current folder is importable",
    )
    evaluate.add_argument(
        "--label",
        action="append",
        default=[],
        help="the Table I row of each --policy, in their order (default: its `label` attribute, else MODULE:CALLABLE, "
        "or a folder's name)",
    )
    evaluate.add_argument(
        "--run",
        action="append",
        default=[],
        metavar="METHOD=RUN_DIR",
        help="trained run directory of a method that learns (repeatable)",
    )
    evaluate.add_argument(
        "--runs-from",
        type=Path,
        metavar="OUT",
        help="take missing run directories from a pipeline output: OUT/runs/METHOD/fraction-1.00",
    )
    evaluate.add_argument(
        "--backbone",
        help="backbone spec (default: the one the --run / --runs-from runs were trained on, found by the spec their "
        "training recorded or by fingerprint; without runs: offline)",
    )
    evaluate.add_argument("--out", type=Path, help="results JSON (the markdown goes beside it, .md)")
    evaluate.add_argument(
        "--subsets",
        nargs="+",
        type=scored_split,
        default=list(TEST_SUBSETS),
        metavar="SUBSET",
        help=f"test subsets to score (default: all four), dev splits to choose settings on "
        f"({', '.join(SCORED_SPLITS)}), or the subsets of your own catalogue a dataset of `generate --catalogue` holds",
    )
    evaluate.add_argument("--limit", type=count(1, MAX_SCENES), help="first N scenes of each subset")
    evaluate.add_argument(
        "--physical",
        type=count(0, MAX_SCENES, none_below=-1),
        default=None,
        metavar="K",
        help="physical check on the first K scenes of each subset (default 50; 0: none; -1: all)",
    )
    evaluate.add_argument("--parser", help="parser for methods that parse (default: offline)")
    evaluate.add_argument(
        "--num-samples", type=count(1, MAX_SAMPLES), help="placement samples per scene (default: 1024)"
    )
    evaluate.add_argument(
        "--experiment",
        choices=EXPERIMENT_NAMES,
        help="the experiment the runs come from, recorded in the results (each run carries its own recipe; "
        "default: default)",
    )
    evaluate.add_argument(
        "--scale", dest="experiment", choices=EXPERIMENT_NAMES, action=DeprecatedAlias, instead="--experiment"
    )
    evaluate.add_argument(
        "--threshold",
        type=number(0.0, 1.0),
        metavar="P",
        help="refuse a scene whose reference's best token has P below this (default 0: the paper's protocol, always "
        "place; the robot's gate is reported beside Table I as a selective table)",
    )
    evaluate.add_argument("--seed", type=count(0, MAX_SEED), help="default: 0")
    evaluate.add_argument("--chunk-size", type=count(1, MAX_CHUNK), help="scenes per method call (default: 32)")
    evaluate.add_argument(
        "--rerun",
        type=Path,
        metavar="RESULTS.json",
        help="evaluate again from this results JSON (its settings and runs) and compare",
    )
    evaluate.add_argument(
        "--scene-timeout",
        type=seconds,
        default=SCENE_TIMEOUT_S,
        metavar="S",
        help=f"seconds a --policy may take per scene; past them its process is killed, the scene fails as a "
        f"timeout and a fresh process goes on (default {SCENE_TIMEOUT_S:g}; 0: no limit)",
    )
    evaluate.add_argument(
        "--trust-policy",
        action="store_true",
        help="with --rerun: import every policy the results file names (default: only those --policy names again)",
    )
    evaluate.add_argument("--no-progress", action="store_true", help="no progress bars")
    add_executor_arguments(evaluate, "each method's evaluation is a task")
    evaluate.set_defaults(func=_evaluate)


def scored_split(text: str) -> str:
    """A split `evaluate` can score: the benchmark's (SCORED_SPLITS) or a user catalogue's subset name."""
    from ocplace.vocabulary import is_own_subset

    if text in SCORED_SPLITS or is_own_subset(text):
        return text
    raise argparse.ArgumentTypeError(
        f"{text!r} is none of {', '.join(SCORED_SPLITS)}, nor a name a subset of your catalogue can have (lowercase "
        "letters, digits and _)"
    )


def parse_runs(items: list[str]) -> dict[str, Path]:
    from ocplace.errors import EvaluationError

    runs = {}
    for item in items:
        name, sep, directory = item.partition("=")
        if not sep or not name or not directory:
            raise EvaluationError(f"--run takes METHOD=RUN_DIR, got {item!r}")
        runs[name] = Path(directory)
    return runs


def physical_setting(value: int | None, default: int | None) -> int | None:
    if value is None:
        return default
    return None if value == -1 else value  # `count(0, none_below=-1)` lets nothing else below 0 through


def command_record(args: argparse.Namespace) -> dict:
    """The command line as typed (`argv`) and as parsed (`arguments`: exact even when called in-process)."""
    arguments = {key: value for key, value in vars(args).items() if key != "func"}
    return {
        "argv": ["ocplace", *sys.argv[1:]],
        "arguments": {
            key: value if isinstance(value, (bool, int, float, str, type(None))) else str(value)
            for key, value in arguments.items()
        },
    }


def _evaluate(args: argparse.Namespace) -> int:
    if args.rerun is not None:
        return _rerun(args)
    from ocplace.errors import EvaluationError
    from ocplace.eval.harness import DEFAULT_PHYSICAL_SCENES, EvalSettings
    from ocplace.eval.results import build_results
    from ocplace.eval.table import terminal_summary, write_outputs
    from ocplace.experiments.evaluation import evaluate_runs, method_runs
    from ocplace.methods.registry import method_run, method_specs, select_specs
    from ocplace.runtime import open_executor

    if args.dataset is None or args.out is None:
        raise EvaluationError("`ocplace evaluate` needs --dataset DIR and --out RESULTS.json (or --rerun RESULTS.json)")
    settings = config_from_arguments(
        args,
        EvalSettings(
            subsets=tuple(args.subsets), physical_scenes=physical_setting(args.physical, DEFAULT_PHYSICAL_SCENES)
        ),
        fields=EVAL_SETTINGS_OPTIONS,
    )
    settings.validate()
    store = checked_out(args.out)
    specs = method_specs()
    methods = args.methods or ("" if args.policy else "all")
    runs = method_runs(select_specs(methods, specs) if methods else [], parse_runs(args.run), args.runs_from)
    policies = _policy_specs(args.policy, args.label, args.scene_timeout)
    if args.backbone is None:
        settings = _runs_backbone(settings, [run.run_dir for run in runs if specs[run.method].uses_backbone])
    runs += [method_run(spec) for spec in policies]
    specs |= {spec.name: spec for spec in policies}
    with open_executor(executor_config(args)) as executor:
        evaluations = evaluate_runs(specs, runs, args.dataset, settings, executor, not args.no_progress, store)
    results = build_results(evaluations, args.dataset, settings, command_record(args))
    write_outputs(results, args.out)
    shutil.rmtree(store, ignore_errors=True)
    print(terminal_summary(results))
    print(f"wrote {args.out} and {args.out.with_suffix('.md')} (every table)")
    broken = [message for spec in policies if (message := _all_failed(spec.name, evaluations))]
    for message in broken:
        print(f"ocplace evaluate: {message}", file=sys.stderr)
    return 1 if broken else 0


def _runs_backbone(settings, run_dirs: list):
    """`settings` on the backbone the runs were trained on (no --backbone given), found as `place` and `export`
    find it; unchanged without runs."""
    import dataclasses

    from ocplace.methods.run_backbone import runs_backbone

    spec = runs_backbone([run_dir for run_dir in run_dirs if run_dir is not None])
    if spec is None:
        return settings
    print(f"backbone: {spec} (the one the runs were trained on)", flush=True)
    return dataclasses.replace(settings, backbone=spec)


def _all_failed(name: str, evaluations) -> str | None:
    """What to say when the policy `name` failed every scene with an error (never placed): a policy that cannot
    run is no row of Table I, and a script should see it in the exit status."""
    import collections

    evaluation = next(e for e in evaluations if e.method == name)
    failures = [o.failure for outcomes in evaluation.subsets.values() for o in outcomes]
    if not failures or any(failure is None for failure in failures):
        return None
    (most, count), *_ = collections.Counter(f.partition(":")[0] for f in failures).most_common(1)
    return (
        f"the policy {name} placed nothing: all {len(failures)} scenes failed, {count} of them with {most} "
        f"(first: {failures[0][:300]}); the table above is written, but fix the policy before reading it (exit 1)"
    )


def checked_out(out: Path) -> Path:
    """The store of `--out` (`finished_store`), after checking, before any work, that OUT names a results file that
    can be written and that the store can live beside it: never `.`, `..` or another folder, never a file where the
    store goes. OutputError saying what to give instead."""
    from ocplace.errors import OutputError
    from ocplace.paths import check_writable

    if out.name in ("", ".", "..") or out.is_dir():
        raise OutputError(f"--out {out} is a folder; give the results file to write, e.g. --out {out / 'results.json'}")
    store = finished_store(out)
    if store.exists() and not store.is_dir():
        raise OutputError(
            f"{store} is a file, where --out {out} keeps its finished evaluations while it runs; move it, or choose "
            "another --out"
        )
    check_writable(out)
    check_writable(store, as_folder=True)
    return store


def finished_store(out: Path) -> Path:
    """Where the evaluations of `--out` OUT.json are kept while the command runs (OUT.evaluations/ beside it):
    a killed command run again with the same arguments reuses them; removed once OUT.json is written."""
    return out.resolve().with_name(out.stem + ".evaluations")  # absolute: a Ray worker runs elsewhere


def _policy_specs(references: list[str], labels: list[str], scene_timeout_s: float) -> list:
    """The spec of each `--policy`, imported here (the current folder first on the import path, as for `python -m`)."""
    from ocplace.errors import EvaluationError
    from ocplace.methods.external_policy import policy_spec

    if labels and len(labels) != len(references):
        raise EvaluationError(f"give one --label per --policy, or none: got {len(labels)} for {len(references)}")
    if references:
        _import_from_here()
    named: list[str | None] = list(labels) or [None] * len(references)
    return [policy_spec(ref, label, scene_timeout_s) for ref, label in zip(references, named)]


def _import_from_here() -> None:
    """Puts the current folder first on the import path, as `python -m` does, for policies' modules;
    evaluation workers are spawned, so they inherit it."""
    if os.getcwd() not in sys.path:
        sys.path.insert(0, os.getcwd())


def _rerun(args: argparse.Namespace) -> int:
    from ocplace.eval.results import compare, read_results
    from ocplace.eval.table import write_outputs
    from ocplace.experiments.evaluation import rerun
    from ocplace.methods.external_policy import with_policies
    from ocplace.methods.registry import method_specs
    from ocplace.runtime import open_executor

    original = read_results(args.rerun)
    _import_from_here()  # a policy's module, as when it was evaluated from here
    specs = with_policies(
        method_specs(), original, set(args.policy), args.trust_policy, scene_timeout_s=args.scene_timeout
    )
    with open_executor(executor_config(args)) as executor:
        fresh = rerun(original, specs, progress=not args.no_progress, command=command_record(args), executor=executor)
    out = args.out or args.rerun.with_name(args.rerun.stem + ".rerun.json")
    write_outputs(fresh, out)
    differences = compare(original, fresh)
    for line in differences[:50]:
        print(line)
    if len(differences) > 50:
        print(f"... and {len(differences) - 50} more differences")
    print(f"{'reproduced exactly' if not differences else f'{len(differences)} differences'}: {args.rerun} vs {out}")
    return 0 if not differences else 1
