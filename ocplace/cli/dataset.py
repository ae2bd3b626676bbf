"""CLI: `ocplace dataset verify|show|check`: check or draw a generated dataset."""

from __future__ import annotations

import argparse
from pathlib import Path

from ocplace.cli.executor_options import add_executor_arguments, executor_config
from ocplace.cli.generate import SPLIT_CHOICES
from ocplace.cli.options import add_dataset_argument, dataset_of
from ocplace.sim.dataset.config import SPLIT_NAMES


def register(subparsers: argparse._SubParsersAction) -> None:
    dataset = subparsers.add_parser("dataset", help="check or draw a generated dataset")
    actions = dataset.add_subparsers(dest="action", metavar="ACTION", required=True)
    verify = actions.add_parser(
        "verify",
        help="check every file against the manifest's sha256 and the schema, "
        "and report what the manifest does not list",
    )
    add_dataset_argument(verify, "dataset folder (`ocplace generate`)", required=True)
    verify.set_defaults(func=_verify)
    show = actions.add_parser("show", help="draw one scene with its instruction, truth and feasible region")
    add_dataset_argument(show, "dataset folder (`ocplace generate`)", required=True)
    show.add_argument("--id", required=True, help="scene id (e.g. seen-00003) or index into --split")
    show.add_argument("--split", default="seen", help="split used with a numeric --id")
    show.add_argument("--out", type=Path, default=Path("scene.png"), help="PNG to write (default: scene.png)")
    show.set_defaults(func=_show)
    check = actions.add_parser(
        "check", help="score the oracle placements with the success metric (and the physical drop check)"
    )
    add_dataset_argument(check, "dataset folder (`ocplace generate`)", required=True)
    check.add_argument("--split", choices=SPLIT_CHOICES, default="all", help="check only this split (default: all)")
    check.add_argument("--physical", action="store_true", help="also drop the held object in MuJoCo")
    add_executor_arguments(check, "with --physical, each chunk of scenes is a task")
    check.set_defaults(func=_check)


def _verify(args: argparse.Namespace) -> int:
    from ocplace.sim.dataset.job import verify_dataset

    problems = verify_dataset(dataset_of(args))
    for scene, problem in problems:
        print(f"{scene}: {problem}")
    if problems:
        print(
            f"{len(problems)} problems; rerun `ocplace generate --out {dataset_of(args)}` with the same options "
            "to regenerate exactly the damaged scenes, and delete what the manifest does not list"
        )
        return 1
    print(f"{dataset_of(args)}: every file matches the manifest")
    return 0


def _show(args: argparse.Namespace) -> int:
    from ocplace.errors import DatasetError
    from ocplace.sim.dataset.generate import scene_id
    from ocplace.sim.dataset.job import listed_scenes
    from ocplace.sim.dataset.show import scene_figure
    from ocplace.sim.figures import save_png

    identifier = scene_id(args.split, int(args.id)) if args.id.isdigit() else args.id
    split = identifier.rsplit("-", 1)[0]
    # Through the manifest, as every reader: a scene edited after generation is refused, never drawn as the dataset's.
    scene = next((s for s in listed_scenes(dataset_of(args), split) if s.name == identifier), None)
    if scene is None:
        raise DatasetError(f"{dataset_of(args)} lists no scene {identifier!r} in its manifest")
    record = scene.read()
    save_png(args.out, scene_figure(record))
    print(f"wrote {args.out}: {record.instruction}")
    return 0


def _check(args: argparse.Namespace) -> int:
    from ocplace.runtime import open_executor
    from ocplace.sim.dataset.check import check_oracle
    from ocplace.sim.dataset.job import read_manifest

    listed = {relative.split("/")[0] for relative in read_manifest(dataset_of(args))["files"]}
    ordered = [s for s in SPLIT_NAMES if s in listed] + sorted(listed - set(SPLIT_NAMES))  # a catalogue's subsets last
    splits = ordered if args.split == "all" else [args.split]
    with open_executor(executor_config(args)) as executor:
        report = check_oracle(dataset_of(args), splits, args.physical, executor)
    total = {"scenes": 0, "metric_success": 0, "physical_success": 0}
    for split, row in report.items():
        line = f"{split:>12}: metric {row['metric_success']}/{row['scenes']}"
        if args.physical:
            line += f", physical {row['physical_success']}/{row['scenes']}"
        print(line)
        for key in total:
            total[key] += row.get(key, 0)
    print(
        f"{'all':>12}: metric {total['metric_success']}/{total['scenes']}"
        + (
            f", physical {total['physical_success']}/{total['scenes']} "
            f"({100 * total['physical_success'] / total['scenes']:.1f}%)"
            if args.physical
            else ""
        )
    )
    return 0 if total["metric_success"] == total["scenes"] else 1
