"""`ocplace train`: the CLIP-Adapters trained on cached features, or any Table I row through its method."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

from ocplace.cli.options import (
    MAX_SEED,
    MAX_WORKERS,
    add_config_arguments,
    add_dataset_argument,
    add_set_argument,
    config_from_arguments,
    count,
    number,
)
from ocplace.methods.ours.recipe import (  # light: no JAX behind it
    OursRecipe,
    default_config,
    paper_config,
    smoke_config,
)
from ocplace.models.adapter_settings import AdapterSettings
from ocplace.runtime.width import TRAIN_CPUS, pin_jax_width
from ocplace.train.schedule import Schedule
from ocplace.vocabulary import EXPERIMENT_NAMES


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "train",
        help="train the CLIP-Adapters on cached features, or any Table I row (--method)",
        description="With --features: Ours' adapters by Adam on cached backbone features, steps fused with "
        "lax.scan. With --method: that registered row trained on --dataset through its method, with its recipe "
        "from --experiment (as `ocplace reproduce` trains it). Resumes from the newest checkpoint in --out; the "
        "same seed gives the same weights.",
    )
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--features", type=Path, help="training feature file (Ours' adapters)")
    source.add_argument(
        "--method",
        help="a registered method that learns, trained on --dataset (an unknown name lists them)",
    )
    parser.add_argument("--out", required=True, type=Path, help="run directory")
    row = parser.add_argument_group("with --method")
    add_dataset_argument(row, "dataset folder holding the training split")
    row.add_argument("--backbone", default="offline", help="backbone spec the method trains on (default: offline)")
    row.add_argument(
        "--experiment",
        choices=EXPERIMENT_NAMES,
        default="default",
        help="whose recipe (configs/; default: default)",
    )
    add_set_argument(row, "recipes.no_llm.schedule.steps")
    parser.add_argument("--val-features", type=Path, help="feature file to report validation accuracy on")
    start = parser.add_mutually_exclusive_group()
    start.add_argument("--smoke", action="store_true", help="start from the tiny smoke configuration")
    start.add_argument(
        "--paper-adapters",
        action="store_true",
        help="start from the paper's adapters (ratio 0.2 on both towers, unnormalised; the ours_paper row)",
    )
    parser.add_argument(
        "--cpus",
        type=count(0, MAX_WORKERS),
        default=TRAIN_CPUS,
        help=f"CPUs JAX computes for (default {TRAIN_CPUS}, as `ocplace reproduce` trains: the same recipe gives the "
        "same bits; 1 may be faster on a busy machine, with other last bits; 0: every CPU this process may use)",
    )
    parser.add_argument("--seed", type=count(0, MAX_SEED), help="initial weights and example order (default 0)")
    parser.add_argument(
        "--fraction",
        type=number(0.001, 1.0),
        help="train on this seeded share of the scenes, nested (the sample-efficiency curve; default 1)",
    )
    overrides = parser.add_argument_group(
        "configuration overrides",
        "One flag per field of Ours' recipe (OursRecipe: its adapters, its schedule, its own fields). The defaults "
        "shown are Ours' recipe's, the values a run records: the paper's schedule with rule A's adapters; --smoke "
        "and --paper-adapters start from another recipe.",
    )
    ours = default_config()
    add_config_arguments(overrides, AdapterSettings, defaults=ours.adapters)
    aliases = {"learning_rate": ("--lr",)}
    add_config_arguments(overrides, Schedule, SCHEDULE_FLAGS, aliases=aliases, defaults=ours.schedule)
    add_config_arguments(overrides, OursRecipe, defaults=ours)
    parser.set_defaults(func=run_train)


# Ours trains with Adam: the schedule's other fields are the flags' (`optimiser` is an image tower's choice).
SCHEDULE_FLAGS = tuple(field.name for field in dataclasses.fields(Schedule) if field.name != "optimiser")


def train_config_from_args(args: argparse.Namespace) -> OursRecipe:
    base = smoke_config() if args.smoke else paper_config() if args.paper_adapters else default_config()
    return dataclasses.replace(
        config_from_arguments(args, base),
        adapters=config_from_arguments(args, base.adapters),
        schedule=config_from_arguments(args, base.schedule, SCHEDULE_FLAGS),
    )


def recipe_flags_given(args: argparse.Namespace) -> list[str]:
    """The recipe flags of --features given on the command line."""
    names = [field.name for owner in (AdapterSettings, Schedule, OursRecipe) for field in dataclasses.fields(owner)]
    return [name for name in names if getattr(args, name, None) is not None]


def run_train(args) -> int:
    if args.method is not None:
        return train_method(args)
    from ocplace.errors import TrainingError
    from ocplace.experiments.experiment import number_problems

    config = train_config_from_args(args)
    seed, fraction = run_keys(args)
    problems = number_problems(config, "")
    if problems:
        raise TrainingError("invalid training configuration: " + "; ".join(problems))
    config.validate()
    if args.cpus:  # before JAX starts, as in each task of `reproduce`: the width decides the last bits
        pin_jax_width(args.cpus)
    from ocplace.methods.ours.train import train_ours as train
    from ocplace.models.features import load_features

    features = load_features(args.features)
    val_features = load_features(args.val_features, features.info.backbone_fingerprint) if args.val_features else None
    result = train(features, args.out, config, seed, fraction, val_features=val_features)
    print(
        f"{result.run_dir}: {result.steps} steps, train grounding accuracy "
        f"{result.train_accuracy.tuple_accuracy:.4f} per tuple, {result.train_accuracy.scene_accuracy:.4f} per scene"
    )
    if result.val_accuracy is not None:
        print(
            f"validation: {result.val_accuracy.tuple_accuracy:.4f} per tuple, "
            f"{result.val_accuracy.scene_accuracy:.4f} per scene"
        )
    return 0


def train_method(args: argparse.Namespace) -> int:
    """The row `args.method` trained through its `MethodSpec` (its shared inputs made first), as a task of
    `reproduce` trains it; the recipe flags belong to --features."""
    from ocplace import configs
    from ocplace.cli.options import apply_overrides
    from ocplace.errors import ConfigError
    from ocplace.experiments.experiment import read_overrides
    from ocplace.experiments.training import train_row
    from ocplace.paths import check_writable

    if recipe_flags_given(args) or args.smoke or args.paper_adapters or args.val_features:
        raise ConfigError("with --method the recipe is the experiment's: change it with --set recipes.NAME.FIELD=VALUE")
    if args.dataset is None:
        raise ConfigError("--method trains on a dataset: give --dataset DATA")
    seed, fraction = run_keys(args)
    experiment = apply_overrides(configs.get(args.experiment), read_overrides(args.overrides))
    check_writable(args.out, as_folder=True)
    run_dir, reused, label = train_row(
        args.method, experiment, args.dataset, args.backbone, args.out, seed, fraction, args.cpus
    )
    done = "done before" if reused else "trained"
    print(f"{run_dir}: {label} {done} ({args.experiment} recipe, fraction {fraction:g}, seed {seed})")
    return 0


def run_keys(args: argparse.Namespace) -> tuple[int, float]:
    """(seed, fraction) of the run: what a reproduce task takes from its context."""
    from ocplace.errors import ConfigError

    fraction, seed = 1.0 if args.fraction is None else args.fraction, args.seed or 0
    if not 0.0 < fraction <= 1.0:
        raise ConfigError(f"--fraction lies in (0, 1], got {fraction}")
    return seed, fraction
