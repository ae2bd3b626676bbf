"""`ocplace train`: the CLIP-Adapters trained on cached features."""

from __future__ import annotations

import argparse
from pathlib import Path

from ocplace.cli.options import add_config_arguments, config_from_arguments, count
from ocplace.runtime.width import TRAIN_CPUS, pin_jax_width
from ocplace.train.config import TrainConfig, default_config, paper_config, smoke_config  # light: no JAX behind it


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "train",
        help="train the CLIP-Adapters on cached features",
        description="Adam on cached backbone features, steps fused with lax.scan. Resumes from the newest "
        "checkpoint in --out; the same seed gives the same weights.",
    )
    parser.add_argument("--features", required=True, type=Path, help="training feature file")
    parser.add_argument("--out", required=True, type=Path, help="run directory")
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
        type=count(0),
        default=TRAIN_CPUS,
        help=f"CPUs JAX computes for (default {TRAIN_CPUS}, as `ocplace reproduce` trains: the same recipe gives the "
        "same bits; 1 may be faster on a busy machine, with other last bits; 0: every CPU this process may use)",
    )
    overrides = parser.add_argument_group(
        "configuration overrides",
        "One flag per TrainConfig field. Defaults: Ours' recipe, the paper's schedule with rule A's adapters "
        "(normalise, residual_ratio 0.1, text_ratio 0.5; the values shown are the class's, the paper's), or the "
        "start --smoke or --paper-adapters names.",
    )
    add_config_arguments(overrides, TrainConfig, aliases={"learning_rate": ("--lr",)})
    parser.set_defaults(func=run_train)


def train_config_from_args(args: argparse.Namespace) -> TrainConfig:
    base = smoke_config() if args.smoke else paper_config() if args.paper_adapters else default_config()
    return config_from_arguments(args, base)


def run_train(args) -> int:
    from ocplace.errors import TrainingError
    from ocplace.experiments.experiment import number_problems

    config = train_config_from_args(args)
    problems = number_problems(config, "")
    if problems:
        raise TrainingError("invalid training configuration: " + "; ".join(problems))
    config.validate()
    if args.cpus:  # before JAX starts, as in each task of `reproduce`: the width decides the last bits
        pin_jax_width(args.cpus)
    from ocplace.models.features import load_features
    from ocplace.train.ours import train_ours as train

    features = load_features(args.features)
    val_features = load_features(args.val_features, features.info.backbone_fingerprint) if args.val_features else None
    result = train(features, args.out, config, val_features=val_features)
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
