"""CLI: `ocplace generate`: the benchmark dataset (resumable)."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

from ocplace.cli.executor_options import add_executor_arguments, executor_config
from ocplace.cli.options import MAX_SCENES, MAX_SEED, count
from ocplace.sim.dataset.config import SPLIT_NAMES
from ocplace.vocabulary import DEV_SPLITS, LIBRARY_SPLITS

SPLIT_CHOICES = ("all", *SPLIT_NAMES)


def register(subparsers: argparse._SubParsersAction) -> None:
    generate = subparsers.add_parser(
        "generate",
        help="generate the benchmark dataset (resumable)",
        description="Drops objects in MuJoCo, renders them and writes scenes with instructions and "
        "ground truth. Defaults are the paper's: train 2000 scenes (450 table, 450 1obj, "
        "1100 2obj) and four test subsets of 400 (90/90/220): the paper's seen, unseen_obj, unseen_inst "
        "and unseen_cat (objects of categories absent from training); with --dev N, the dev splits dev_seen and "
        "dev_colour that settings are chosen on. Rerun to resume.",
    )
    generate.add_argument("--out", type=Path, required=True, help="dataset folder")
    generate.add_argument(
        "--split", choices=SPLIT_CHOICES, default="all", help="generate only this split (default: all)"
    )
    generate.add_argument(
        "--seed", type=count(0, MAX_SEED), default=0, help="the dataset's seed: same seed, same scenes (default 0)"
    )
    generate.add_argument("--train", type=count(0, MAX_SCENES), help="training scenes (default 2000)")
    generate.add_argument("--test", type=count(0, MAX_SCENES), default=400, help="scenes per test subset")
    generate.add_argument(
        "--dev",
        type=count(0, MAX_SCENES),
        default=0,
        help="scenes per dev split (dev_seen, dev_colour; default 0: none, the paper's dataset); their scenes come "
        "from streams of their own, never a test subset's",
    )
    generate.add_argument("--smoke", action="store_true", help="a tiny dataset (12 train, 8 per test subset)")
    generate.add_argument(
        "--test-dataset",
        type=Path,
        metavar="DIR",
        help="also refuse a dev scene that is a test scene of this dataset (the dev splits in a folder of their own)",
    )
    own = generate.add_argument_group(
        "your own objects",
        'a test-only dataset of your catalogue\'s subsets (docs/library.md, "Test on your own objects")',
    )
    own.add_argument(
        "--catalogue",
        type=Path,
        metavar="FILE",
        help="the catalogue built with `ocplace assets build --catalogue FILE`; scenes hold only its objects",
    )
    own.add_argument(
        "--subset",
        action="append",
        default=[],
        metavar="NAME",
        help="a subset of the catalogue to generate (repeatable; default: every subset it defines)",
    )
    own.add_argument(
        "--distractors",
        choices=LIBRARY_SPLITS,
        help="mix in benchmark objects of this library split as distractors (never referred to; default: none)",
    )
    add_executor_arguments(generate, "batches of up to 16 scenes are tasks")
    generate.set_defaults(func=_generate)


def _generate(args: argparse.Namespace) -> int:
    from ocplace.errors import DatasetConfigError
    from ocplace.runtime import open_executor
    from ocplace.sim.dataset.config import SMOKE_SIZES, make_config
    from ocplace.sim.dataset.job import generate_dataset

    if args.catalogue is not None:
        config, splits = _catalogue_config(args)
    else:
        if args.subset or args.distractors:
            raise DatasetConfigError("--subset and --distractors are options of --catalogue FILE")
        train = 2000 if args.train is None else args.train
        if min(train, args.test, args.dev) < 0:
            raise DatasetConfigError("--train, --test and --dev must be >= 0")
        if args.split in DEV_SPLITS and args.dev == 0:
            raise DatasetConfigError(f"{args.split} is a dev split: say how many scenes it holds with --dev N")
        config = make_config(*SMOKE_SIZES, dev=args.dev) if args.smoke else make_config(train, args.test, dev=args.dev)
        config = dataclasses.replace(config, seed=args.seed)
        splits = None if args.split == "all" else [args.split]
    with open_executor(executor_config(args)) as executor:
        manifest = generate_dataset(args.out, config, splits, executor=executor, test_dataset=args.test_dataset)
    for split, counts in manifest["counts"].items():
        print(f"{split:>12}: {sum(counts.values())} scenes {counts}")
    stats = manifest["statistics"]
    print(
        f"resampled: {stats['resamples']['scenes']} scenes, {stats['resamples']['relations']} relation draws; "
        f"{stats['bytes'] / 1e6:.0f} MB in {args.out}"
    )
    return 0


def _catalogue_config(args: argparse.Namespace):
    """The test-only dataset of `--catalogue`: its subsets (or those named), `--test` scenes each."""
    from ocplace.errors import DatasetConfigError
    from ocplace.sim.dataset.config import SMOKE_SIZES, catalogue_config
    from ocplace.sim.library.catalogue_library import catalogue_record
    from ocplace.sim.library.user_catalogue import read_catalogue

    refused = [
        flag
        for flag, given in (("--train", args.train), ("--dev", args.dev), ("--test-dataset", args.test_dataset))
        if given
    ]
    if refused or args.split != "all":
        raise DatasetConfigError(
            f"a catalogue's dataset is test-only: {', '.join(refused) or '--split'} does not apply (choose its "
            "subsets with --subset)"
        )
    catalogue = read_catalogue(args.catalogue)
    subsets = tuple(args.subset) or tuple(s.name for s in catalogue.subsets)
    for name in subsets:
        catalogue.subset(name)
    test = SMOKE_SIZES[1] if args.smoke else args.test
    if test < 1:
        raise DatasetConfigError("--test must be at least 1 scene per subset")
    config = catalogue_config(catalogue_record(catalogue), subsets, test, args.seed, args.distractors)
    return config, None
