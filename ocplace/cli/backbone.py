"""CLI: `ocplace backbone pretrain|eval|path` for the offline backbone."""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

from ocplace.cli.options import MAX_SCENES, MAX_WORKERS, add_dataset_argument, count, dataset_of
from ocplace.vocabulary import SCORED_SPLITS

# `models.offline_recipes.RECIPES`, spelled out so that building the parser imports no JAX (a test
# checks the two agree).
RECIPE_NAMES = ("default", "strict", "task", "demo", "smoke")


def register(subparsers: argparse._SubParsersAction) -> None:
    backbone = subparsers.add_parser("backbone", help="pretrain and measure the offline backbone")
    actions = backbone.add_subparsers(dest="action", metavar="ACTION", required=True)

    pretrain = actions.add_parser(
        "pretrain",
        help="pretrain the offline backbone (resumable)",
        description="Renders crops of the recipe's pool (the furniture corpus; `task`: the benchmark's "
        "training objects) on seen tables and trains the image tower and both projections contrastively "
        "against a frozen MiniLM text tower. Rerun to resume. The result goes to "
        "<cache>/backbones/offline-<hash>/ unless --out is given.",
    )
    pretrain.add_argument(
        "--recipe",
        choices=RECIPE_NAMES,
        default="default",
        help="default: the corpus, <= 30 min on 2 cores; strict: the corpus without test nouns; task: the "
        "benchmark's training objects (the earlier backbone); demo: a few minutes; smoke: seconds",
    )
    pretrain.add_argument("--smoke", action="store_true", help="same as --recipe smoke")
    pretrain.add_argument("--out", type=Path, help="output directory (default: the recipe's cache folder)")
    pretrain.add_argument("--keep-run", action="store_true", help="keep rendered images and checkpoints")
    pretrain.add_argument(
        "--workers",
        type=count(0, MAX_WORKERS),
        default=0,
        help="processes that render (default: every CPU this process may use)",
    )
    pretrain.add_argument("--no-progress", action="store_true", help="no progress bars")
    pretrain.set_defaults(func=_pretrain)

    evaluate = actions.add_parser(
        "eval",
        help="zero-shot grounding and crop-to-name retrieval on benchmark scenes",
        description="Top-1 grounding accuracy among the N+1 visual tokens with no adapters, and "
        "crop-to-name retrieval, for a backbone and for the same architecture at random init.",
    )
    add_dataset_argument(evaluate, "dataset folder (`ocplace generate`)", required=True)
    evaluate.add_argument("--backbone", default="offline", help="backbone spec (default: offline)")
    evaluate.add_argument(
        "--splits", nargs="+", choices=SCORED_SPLITS, default=["seen", "unseen_obj"], help="default: seen unseen_obj"
    )
    evaluate.add_argument(
        "--no-random-init", action="store_true", help="skip the random-initialisation control (offline backbones only)"
    )
    evaluate.add_argument("--limit", type=count(1, MAX_SCENES), help="first N scenes per split")
    evaluate.add_argument("--out", type=Path, help="write the results as JSON here")
    evaluate.set_defaults(func=_eval)

    validate = actions.add_parser(
        "validate",
        help="zero-shot grounding on the corpus' held-out categories (the split pretraining choices are made on)",
        description="Renders (once, cached) benchmark-like scenes of the corpus models of the categories the "
        "recipe holds out of pretraining (head-noun groups that name no benchmark object), and grounds each "
        "of them among its scene's crops. No test subset is involved.",
    )
    validate.add_argument("--backbone", default="offline", help="backbone spec (default: offline, the default recipe)")
    validate.add_argument(
        "--recipe", choices=RECIPE_NAMES, default="default", help="whose held-out categories and protocol"
    )
    validate.add_argument(
        "--scenes", type=count(1, MAX_SCENES), default=100, help="validation scenes rendered (default 100)"
    )
    validate.set_defaults(func=_validate)

    path = actions.add_parser("path", help="print where a recipe's backbone is (or will be) saved")
    path.add_argument("--recipe", choices=RECIPE_NAMES, default="default", help="default: default")
    path.set_defaults(func=_path)


def _pretrain(args: argparse.Namespace) -> int:
    from ocplace.models.offline_recipes import recipe_config
    from ocplace.sim.library import load_library
    from ocplace.train.pretrain.loop import pretrain

    config = recipe_config("smoke" if args.smoke else args.recipe)
    workers = args.workers or len(os.sched_getaffinity(0))
    result = pretrain(
        config, load_library(), args.out, progress=not args.no_progress, keep_run=args.keep_run, render_workers=workers
    )
    timings = ", ".join(f"{k} {v:.0f}" for k, v in result.timings.items())
    print(
        f"offline backbone ({config.recipe}) in {result.directory}\n"
        f"  fingerprint {result.backbone.fingerprint[:16]}, logit scale {result.backbone.logit_scale:.1f}, "
        f"probe loss {result.probe_loss_before:.3f} -> {result.probe_loss_after:.3f}"
        + (f"\n  seconds: {timings}" if timings else " (already built)")
    )
    return 0


def _eval(args: argparse.Namespace) -> int:
    import datetime
    import os

    import jax

    from ocplace.models.backbone import load_backbone
    from ocplace.models.offline_backbone import OfflineBackbone, init_params
    from ocplace.sim.library import load_library
    from ocplace.train.pretrain.evaluate import evaluate_split, format_report

    library = load_library()
    backbone = load_backbone(args.backbone)
    candidates = {"pretrained": backbone}
    if isinstance(backbone, OfflineBackbone) and not args.no_random_init:
        candidates["random_init"] = OfflineBackbone(
            backbone.config, init_params(backbone.config, jax.random.key(0)), backbone.text_tower, source="random init"
        )
    report = {
        "backbone": args.backbone,
        "fingerprint": backbone.fingerprint,
        "data": str(dataset_of(args)),
        "started": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
        "load_average_start": os.getloadavg(),
        "results": {},
    }
    for name, candidate in candidates.items():
        report["results"][name] = {
            split: evaluate_split(candidate, dataset_of(args), split, library, limit=args.limit, progress=True)
            for split in args.splits
        }
    report["load_average_end"] = os.getloadavg()
    print(format_report(report))
    if args.out:
        from ocplace.paths import write_text_atomic

        write_text_atomic(args.out, json.dumps(report, indent=2) + "\n")
        print(f"wrote {args.out}")
    return 0


def _validate(args: argparse.Namespace) -> int:
    from ocplace.errors import ConfigError
    from ocplace.models.backbone import load_backbone
    from ocplace.models.offline_recipes import recipe_config
    from ocplace.sim.corpus.build import build_corpus
    from ocplace.sim.library import load_library
    from ocplace.train.pretrain.validation import validation_grounding, validation_scenes

    if args.scenes < 1:
        raise ConfigError(f"--scenes must be at least 1, got {args.scenes}")
    render = recipe_config(args.recipe).render
    scenes = validation_scenes(load_library(), build_corpus(progress=False), render, args.scenes)
    score = validation_grounding(load_backbone(args.backbone), scenes)
    print(
        f"validation ({args.recipe}, {render.protocol}): grounding top-1 {score['grounding_top1']:.1%} of "
        f"{score['references']} references in {score['scenes']} scenes (chance {score['chance']:.1%}); "
        f"crop -> name top-1 {score['retrieval_top1']:.1%} of {score['names']} names"
    )
    return 0


def _path(args: argparse.Namespace) -> int:
    from ocplace.models.offline_recipes import recipe_dir

    print(recipe_dir(args.recipe))
    return 0
