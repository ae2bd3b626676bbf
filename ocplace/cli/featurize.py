"""`ocplace featurize`: a dataset split encoded by a frozen backbone into a feature file."""

from __future__ import annotations

from pathlib import Path

from ocplace.cli.executor_options import add_executor_arguments, executor_config
from ocplace.cli.options import MAX_SCENES, add_dataset_argument, config_from_arguments, count, dataset_of
from ocplace.runtime.width import TRAIN_CPUS


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "featurize",
        help="encode a dataset split with a frozen backbone into a feature file",
        description="Encodes every scene's crops, workspace image and reference phrases once. The file is "
        "keyed by the backbone fingerprint and the dataset manifest; a second run is a no-op, an "
        "interrupted one resumes.",
    )
    add_dataset_argument(parser, "dataset directory (written by `ocplace generate`)", required=True)
    parser.add_argument(
        "--backbone",
        default="offline",
        help="backbone spec: offline (the default recipe's, the default), offline:RECIPE_OR_DIR, clip:HUB_ID_OR_DIR",
    )
    parser.add_argument("--split", default="train", help="the dataset split to featurise (default: train)")
    parser.add_argument("--out", type=Path, help="feature file (default: in the cache, printed at the end)")
    parser.add_argument("--chunk-scenes", type=count(1, MAX_SCENES), help="scenes per resumable chunk (default: 64)")
    add_executor_arguments(parser, "the split is encoded by one task, in this process unless --ray")
    parser.set_defaults(func=run_featurize)


def run_featurize(args) -> int:
    from ocplace.models.backbone import load_backbone
    from ocplace.models.features import FeaturizeConfig, featurize
    from ocplace.sim.dataset.identity import dataset_hash, split_features_path, split_files
    from ocplace.sim.dataset.loader import iter_examples

    dataset = dataset_of(args)
    executor = executor_config(args)
    config = config_from_arguments(args, FeaturizeConfig(), fields=("chunk_scenes",))
    if executor.kind == "ray":
        print(_featurize_on_ray(args, dataset, config, executor))
        return 0
    backbone = load_backbone(args.backbone)
    num_scenes = len({Path(name).parent for name, _ in split_files(dataset, args.split)})
    path = featurize(
        iter_examples(dataset, args.split),
        backbone,
        args.out or split_features_path(dataset, args.split, backbone.fingerprint),
        dataset_hash=dataset_hash(dataset, args.split),
        config=config,
        total=num_scenes,
    )
    print(path)
    return 0


def _featurize_on_ray(args, dataset: Path, config, executor) -> Path:
    """The split encoded by one Ray task: a fresh worker process whose JAX is as wide as the trainings of
    `reproduce` at demo and default scale, so the features are the same bits."""
    from ocplace.models.features import featurize_split_task
    from ocplace.runtime import Task, map_tasks, open_executor

    arguments = (dataset, args.split, args.backbone, args.out, config)
    task = Task(featurize_split_task, arguments, cpus=TRAIN_CPUS, pinned=True)
    with open_executor(executor) as running:
        return next(map_tasks(running, [task]))[1]
