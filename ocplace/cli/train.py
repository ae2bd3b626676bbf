"""`ocplace featurize` and `ocplace train`."""

from __future__ import annotations

import argparse
import importlib
import importlib.util
from collections.abc import Callable, Iterable
from pathlib import Path

from ocplace.cli.executor_options import add_executor_arguments, executor_config
from ocplace.cli.options import add_config_arguments, config_from_arguments
from ocplace.runtime.width import TRAIN_CPUS, pin_jax_width
from ocplace.train.config import TrainConfig, default_config, smoke_config  # light: no JAX behind it

# The dataset's reader: `iter_examples(dataset_dir, split) -> Iterable[SceneExample]`.
DATASET_READER = ("ocplace.sim.dataset.loader", "iter_examples")


def register(subparsers) -> None:
    if importlib.util.find_spec(DATASET_READER[0]) is not None:  # found without importing (cv2, MuJoCo)
        _register_featurize(subparsers, read_dataset)
    _register_train(subparsers)


def read_dataset(dataset_dir: Path, split: str) -> Iterable:
    module_name, function_name = DATASET_READER
    return getattr(importlib.import_module(module_name), function_name)(dataset_dir, split)


def _register_featurize(subparsers, reader: Callable[[Path, str], Iterable]) -> None:
    parser = subparsers.add_parser(
        "featurize",
        help="encode a dataset split with a frozen backbone into a feature file",
        description="Encodes every scene's crops, workspace image and reference phrases once. The file is "
        "keyed by the backbone fingerprint and the dataset manifest; a second run is a no-op, an "
        "interrupted one resumes.",
    )
    parser.add_argument("dataset", type=Path, help="dataset directory (written by `ocplace generate`)")
    parser.add_argument(
        "--backbone",
        default="offline",
        help="backbone spec: offline (the default recipe's, the default), offline:RECIPE_OR_DIR, clip:HUB_ID_OR_DIR",
    )
    parser.add_argument("--split", default="train")
    parser.add_argument("--out", type=Path, help="feature file (default: in the cache, printed at the end)")
    parser.add_argument("--chunk-scenes", type=int, help="scenes per resumable chunk (default: 64)")
    add_executor_arguments(parser, "the split is encoded by one task, in this process unless --ray")
    parser.set_defaults(func=lambda args: run_featurize(args, reader))


def run_featurize(args, read_examples: Callable[[Path, str], Iterable]) -> int:
    from ocplace.models.backbone import load_backbone
    from ocplace.models.features import FeaturizeConfig, featurize
    from ocplace.sim.dataset.identity import dataset_hash, split_features_path, split_files

    executor = executor_config(args)
    if executor.kind == "ray":
        print(_featurize_on_ray(args, executor))
        return 0
    backbone = load_backbone(args.backbone)
    digest = dataset_hash(args.dataset, args.split)
    num_scenes = len({Path(name).parent for name, _ in split_files(args.dataset, args.split)})
    out = args.out or split_features_path(args.dataset, args.split, backbone.fingerprint)
    path = featurize(
        read_examples(args.dataset, args.split),
        backbone,
        out,
        dataset_hash=digest,
        config=config_from_arguments(args, FeaturizeConfig(), fields=("chunk_scenes",)),
        total=num_scenes,
    )
    print(path)
    return 0


def _featurize_on_ray(args, executor) -> Path:
    """The split encoded by one Ray task: a fresh worker process whose JAX is as wide as the trainings of
    `reproduce` at demo and default scale, so the features are the same bits."""
    from ocplace.eval.experiment import TaskCpus
    from ocplace.models.features import FeaturizeConfig, featurize_split_task
    from ocplace.runtime import Task, map_tasks, open_executor

    config = config_from_arguments(args, FeaturizeConfig(), fields=("chunk_scenes",))
    arguments = (args.dataset, args.split, args.backbone, args.out, config)
    task = Task(featurize_split_task, arguments, cpus=TaskCpus().train, fresh_process=True)
    with open_executor(executor) as running:
        return next(map_tasks(running, [task]))[1]


def _register_train(subparsers) -> None:
    parser = subparsers.add_parser(
        "train",
        help="train the CLIP-Adapters on cached features",
        description="Adam on cached backbone features, steps fused with lax.scan. Resumes from the newest "
        "checkpoint in --out; the same seed gives the same weights.",
    )
    parser.add_argument("--features", required=True, type=Path, help="training feature file")
    parser.add_argument("--out", required=True, type=Path, help="run directory")
    parser.add_argument("--val-features", type=Path, help="feature file to report validation accuracy on")
    parser.add_argument("--smoke", action="store_true", help="start from the tiny smoke configuration")
    parser.add_argument(
        "--cpus",
        type=int,
        default=TRAIN_CPUS,
        help=f"CPUs JAX computes for (default {TRAIN_CPUS}, as `ocplace reproduce` trains: the same recipe gives the "
        "same bits; 1 may be faster on a busy machine, with other last bits; 0: every CPU this process may use)",
    )
    overrides = parser.add_argument_group(
        "configuration overrides",
        "One flag per TrainConfig field. Defaults: the paper's schedule (shown), or with --smoke the smoke one.",
    )
    add_config_arguments(overrides, TrainConfig, aliases={"learning_rate": ("--lr",)})
    parser.set_defaults(func=run_train)


def train_config_from_args(args: argparse.Namespace) -> TrainConfig:
    base = smoke_config() if args.smoke else default_config()
    return config_from_arguments(args, base)


def run_train(args) -> int:
    if args.cpus:  # before JAX starts, as in each task of `reproduce`: the width decides the last bits
        pin_jax_width(args.cpus)
    from ocplace.models.features import load_features
    from ocplace.train.loop import train

    config = train_config_from_args(args)
    config.validate()
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
