"""CLI: `ocplace reproduce` (one experiment end to end) and `ocplace figures` (the paper's figures of its results)."""

from __future__ import annotations

import argparse
from pathlib import Path

from ocplace.cli.evaluate import command_record, physical_setting
from ocplace.cli.executor_options import add_executor_arguments, executor_config
from ocplace.cli.options import MAX_SCENES, MAX_SEED, DeprecatedAlias, add_dataset_argument, add_set_argument, count
from ocplace.vocabulary import EXPERIMENT_NAMES, FIGURE_FORMATS


def register(subparsers: argparse._SubParsersAction) -> None:
    reproduce = subparsers.add_parser(
        "reproduce",
        help="the whole pipeline: library, dataset, backbone, training, evaluation, tables",
        description="Builds the object library, generates the dataset, pretrains the offline backbone, "
        "trains every registered method (and, in the default experiment, the data fractions), "
        "evaluates them and writes results.json, results.md and the paper's figures (OUT/figures). "
        "Every step skips what is already done: rerun to resume.",
    )
    reproduce.add_argument(
        "--experiment", choices=EXPERIMENT_NAMES, default="demo", help="which experiment (configs/) to run"
    )
    reproduce.add_argument(
        "--scale", dest="experiment", choices=EXPERIMENT_NAMES, action=DeprecatedAlias, instead="--experiment"
    )
    reproduce.add_argument("--out", type=Path, help="output folder (default: out/demo, out/reproduce, out/smoke)")
    reproduce.add_argument("--backbone", help="use this backbone spec instead of pretraining the offline one")
    reproduce.add_argument(
        "--methods",
        help="comma-separated method names, or `all` (default: the experiment's: "
        "every method; in the demo experiment Ours, w/o Adapter and w/o LLM)",
    )
    reproduce.add_argument(
        "--seeds",
        type=count(1, 100),
        metavar="N",
        help="train and evaluate every run with N seeds; Table I shows mean and spread (default: the experiment's, 1)",
    )
    reproduce.add_argument(
        "--backbone-seeds",
        type=count(1, 100),
        metavar="N",
        help="pretrain the backbone with N seeds and train and evaluate the seeded methods on each (default: 1)",
    )
    add_dataset_argument(reproduce, "dataset folder to use, or to generate into (default: OUT/dataset)")
    reproduce.add_argument(
        "--fractions",
        type=_fraction,
        nargs="+",
        metavar="F",
        help="training-set fractions of the sample-efficiency study (default: the experiment's)",
    )
    reproduce.add_argument(
        "--physical",
        type=count(0, MAX_SCENES, none_below=-1),
        default=None,
        metavar="K",
        help="physical check on the first K scenes per subset (default: the experiment's; -1: all)",
    )
    reproduce.add_argument(
        "--score-catalogue",
        type=Path,
        action="append",
        default=[],
        metavar="DIR",
        help="also score every row on this test-only dataset of your own catalogue (`ocplace generate --catalogue`), "
        'into OUT/<catalogue>.results.json; repeatable (docs/library.md, "Test on your own objects")',
    )
    add_set_argument(reproduce, "recipes.ours.schedule.steps or dataset.train_scenes (applied after the other options)")
    reproduce.add_argument("--no-progress", action="store_true", help="no progress bars")
    add_executor_arguments(
        reproduce, "objects, scenes, the pretraining, each training and each evaluation are tasks of one graph"
    )
    reproduce.set_defaults(func=_reproduce)

    figures = subparsers.add_parser(
        "figures",
        help="the paper's Fig. 5, 6 and 7 from a results JSON",
        description="Draws Fig. 5 (placement densities on the first `seen` scene), Fig. 6 (each method's "
        "placement in chosen test scenes; needs Ours and CLIPort-Place evaluated) and Fig. 7 "
        "(sample efficiency, mean and spread over the seeds; needs several training fractions), each with its legend.",
    )
    figures.add_argument("results", type=Path, help="results JSON of `ocplace evaluate` or `ocplace reproduce`")
    add_dataset_argument(figures, "the evaluated dataset (default: the one the results name)")
    figures.add_argument(
        "--out", type=Path, help="output folder (default: figures/ beside the results file, where `reproduce` writes)"
    )
    figures.add_argument("--seed", type=count(0, MAX_SEED), default=0, help="seed of Fig. 5's relations and samples")
    figures.add_argument("--format", choices=FIGURE_FORMATS, default="png", help="file format (default: png)")
    figures.add_argument(
        "--dpi", type=count(10, 1200), default=150, help="resolution of a PNG (default: 150; 10 to 1200)"
    )
    figures.set_defaults(func=_figures)


def _fraction(text: str) -> float:
    value = float(text)
    if not 0.0 < value <= 1.0:
        raise argparse.ArgumentTypeError(f"a training-set fraction lies in (0, 1], got {text}")
    return value


def _reproduce(args: argparse.Namespace) -> int:
    import dataclasses

    from ocplace import configs
    from ocplace.cli.options import apply_overrides
    from ocplace.errors import ConfigError
    from ocplace.experiments.experiment import read_overrides
    from ocplace.methods.registry import registered_names
    from ocplace.paths import check_writable

    experiment = configs.get(args.experiment)
    plan, sizes = experiment.evaluation, experiment.dataset
    if args.methods == "all":
        plan = dataclasses.replace(plan, methods=None)
    elif args.methods:
        plan = dataclasses.replace(plan, methods=tuple(n.strip() for n in args.methods.split(",") if n.strip()))
    if args.fractions:
        plan = dataclasses.replace(plan, fractions=tuple(sorted(set(args.fractions))))
    if args.seeds is not None:
        if args.seeds < 1:
            raise ConfigError(f"--seeds must be at least 1, got {args.seeds}")
        plan = dataclasses.replace(plan, seeds=args.seeds)
    if args.backbone_seeds is not None:  # checked with the experiment, below
        plan = dataclasses.replace(plan, backbone_seeds=args.backbone_seeds)
    if args.physical is not None:
        sizes = dataclasses.replace(sizes, physical_scenes=physical_setting(args.physical, sizes.physical_scenes))
    overrides = read_overrides(args.overrides)
    experiment = apply_overrides(dataclasses.replace(experiment, evaluation=plan, dataset=sizes), overrides)
    # Checked before the pipeline (and JAX behind it) is imported: a value that cannot work fails at once.
    experiment.validate()
    unknown = experiment.evaluation.unknown_methods(registered_names())
    if unknown:
        raise ConfigError(f"experiment {experiment.name!r} cannot run: {'; '.join(unknown)}")
    check_writable(args.out or experiment.out, as_folder=True)
    from ocplace.experiments.pipeline import PipelineConfig, run_pipeline

    config = PipelineConfig(
        experiment,
        backbone=args.backbone or None,
        dataset=args.dataset,
        executor=executor_config(args),
        progress=not args.no_progress,
        own_datasets=tuple(args.score_catalogue),
    )
    summary = run_pipeline(config, args.out or experiment.out, command=command_record(args))
    print(summary.terminal)
    for path in summary.own_results:
        print(f"your objects: {path} and {path.with_suffix('.md')}")
    print(summary.report())
    return 1 if summary.errors else 0


def _figures(args: argparse.Namespace) -> int:
    from ocplace.eval.figures import write_figures
    from ocplace.eval.results import read_results
    from ocplace.models.placement.figures import FigureStyle

    style = FigureStyle(args.format, args.dpi)
    style.validate()  # before the results are read: a bad --dpi writes nothing
    out = args.out or args.results.parent / "figures"
    for path in write_figures(read_results(args.results), out, args.dataset, args.seed, style):
        print(f"wrote {path}")
    return 0
