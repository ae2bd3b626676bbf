"""CLI: `ocplace generate` and `ocplace dataset verify|show|check`."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

from ocplace.cli.executor_options import add_executor_arguments, executor_config
from ocplace.sim.dataset.config import SPLIT_NAMES

SPLIT_CHOICES = ("all", *SPLIT_NAMES)


def register(subparsers: argparse._SubParsersAction) -> None:
    generate = subparsers.add_parser(
        "generate",
        help="generate the benchmark dataset (resumable)",
        description="Drops objects in MuJoCo, renders them and writes scenes with instructions and "
        "ground truth. Defaults are the paper's: train 2000 scenes (450 table, 450 1obj, "
        "1100 2obj) and four test subsets of 400 (90/90/220): the paper's seen, unseen_obj, unseen_inst "
        "and unseen_cat (objects of categories absent from training). Rerun to resume.",
    )
    generate.add_argument("--out", type=Path, required=True, help="dataset folder")
    generate.add_argument("--split", choices=SPLIT_CHOICES, default="all")
    generate.add_argument("--seed", type=int, default=0)
    generate.add_argument("--train", type=int, default=2000, help="training scenes")
    generate.add_argument("--test", type=int, default=400, help="scenes per test subset")
    generate.add_argument("--smoke", action="store_true", help="a tiny dataset (12 train, 8 per test subset)")
    add_executor_arguments(generate, "batches of up to 16 scenes are tasks")
    generate.set_defaults(func=_generate)

    dataset = subparsers.add_parser("dataset", help="check or draw a generated dataset")
    actions = dataset.add_subparsers(dest="action", metavar="ACTION", required=True)
    verify = actions.add_parser(
        "verify",
        help="check every file against the manifest's sha256 and the schema, "
        "and report what the manifest does not list",
    )
    verify.add_argument("dir", type=Path)
    verify.set_defaults(func=_verify)
    show = actions.add_parser("show", help="draw one scene with its instruction, truth and feasible region")
    show.add_argument("dir", type=Path)
    show.add_argument("--id", required=True, help="scene id (e.g. seen-00003) or index into --split")
    show.add_argument("--split", default="seen", help="split used with a numeric --id")
    show.add_argument("--out", type=Path, default=Path("scene.png"))
    show.set_defaults(func=_show)
    check = actions.add_parser(
        "check", help="score the oracle placements with the success metric (and the physical drop check)"
    )
    check.add_argument("dir", type=Path)
    check.add_argument("--split", choices=SPLIT_CHOICES, default="all")
    check.add_argument("--physical", action="store_true", help="also drop the held object in MuJoCo")
    add_executor_arguments(check, "with --physical, each chunk of scenes is a task")
    check.set_defaults(func=_check)


def _generate(args: argparse.Namespace) -> int:
    from ocplace.errors import DatasetConfigError
    from ocplace.runtime import open_executor
    from ocplace.sim.dataset.config import make_config, smoke_config
    from ocplace.sim.dataset.job import generate_dataset

    if args.train < 0 or args.test < 0:
        raise DatasetConfigError("--train and --test must be >= 0")
    config = smoke_config() if args.smoke else make_config(args.train, args.test)
    config = dataclasses.replace(config, seed=args.seed)
    splits = None if args.split == "all" else [args.split]
    with open_executor(executor_config(args)) as executor:
        manifest = generate_dataset(args.out, config, splits, executor=executor)
    for split, counts in manifest["counts"].items():
        print(f"{split:>12}: {sum(counts.values())} scenes {counts}")
    stats = manifest["statistics"]
    print(
        f"resampled: {stats['resamples']['scenes']} scenes, {stats['resamples']['relations']} relation draws; "
        f"{stats['bytes'] / 1e6:.0f} MB in {args.out}"
    )
    return 0


def _verify(args: argparse.Namespace) -> int:
    from ocplace.sim.dataset.job import verify_dataset

    problems = verify_dataset(args.dir)
    for scene, problem in problems:
        print(f"{scene}: {problem}")
    if problems:
        print(
            f"{len(problems)} problems; rerun `ocplace generate --out {args.dir}` with the same options "
            "to regenerate exactly the damaged scenes, and delete what the manifest does not list"
        )
        return 1
    print(f"{args.dir}: every file matches the manifest")
    return 0


def _show(args: argparse.Namespace) -> int:
    from ocplace.sim.dataset.generate import scene_id
    from ocplace.sim.dataset.records import read_scene
    from ocplace.sim.dataset.show import scene_figure
    from ocplace.sim.figures import save_png

    identifier = scene_id(args.split, int(args.id)) if args.id.isdigit() else args.id
    split = identifier.rsplit("-", 1)[0]
    record = read_scene(args.dir / split / identifier)
    save_png(args.out, scene_figure(record))
    print(f"wrote {args.out}: {record.instruction}")
    return 0


def _check(args: argparse.Namespace) -> int:
    from ocplace.runtime import open_executor
    from ocplace.sim.dataset.check import check_oracle
    from ocplace.sim.dataset.job import read_manifest

    listed = {relative.split("/")[0] for relative in read_manifest(args.dir)["files"]}
    splits = [s for s in SPLIT_NAMES if s in listed] if args.split == "all" else [args.split]
    with open_executor(executor_config(args)) as executor:
        report = check_oracle(args.dir, splits, args.physical, executor)
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
