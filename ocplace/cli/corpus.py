"""CLI: `ocplace corpus build` and `ocplace corpus list`: the offline backbone's pretraining corpus."""

from __future__ import annotations

import argparse
from pathlib import Path

from ocplace.sim.corpus.cutout_sources import CUTOUT_SOURCES
from ocplace.sim.corpus.selection import PROTOCOLS

VIEWS = ("pool", "validation", "test-nouns", "skipped")


def register(subparsers: argparse._SubParsersAction) -> None:
    corpus = subparsers.add_parser(
        "corpus",
        help="build or list the pretraining corpus (furniture catalogues)",
        description="The offline backbone's pretraining corpus: Debian's sweethome3d-furniture "
        "catalogues, selected by size and converted into the cache (docs/offline_backbone.md).",
    )
    actions = corpus.add_subparsers(dest="action", metavar="ACTION", required=True)
    build = actions.add_parser("build", help="convert the selected models into the cache (a no-op when cached)")
    build.add_argument("--source", type=Path, help="a folder of .sh3f catalogues (default: Debian's package)")
    build.add_argument(
        "--large", action="store_true", help="also the models over 40 cm, shrunk (the large tier; a few minutes)"
    )
    build.add_argument(
        "--cutouts",
        nargs="+",
        choices=tuple(CUTOUT_SOURCES),
        default=(),
        metavar="SOURCE",
        help="also these images as thin cut-outs: stamps (Tux Paint's, apt package tuxpaint-stamps-default), emoji "
        "(Fluent Emoji 3-D, fetched with npm); under a minute each",
    )
    build.set_defaults(func=_build)
    listing = actions.add_parser("list", help="show the corpus under a protocol")
    listing.add_argument(
        "--protocol", choices=PROTOCOLS, default="open", help="which pretraining protocol's pool (default: open)"
    )
    listing.add_argument(
        "--show",
        choices=VIEWS,
        default="pool",
        help="pool: what pretraining renders; validation: the models of the held-out categories; test-nouns: the "
        "models whose names hold a test object's noun (kept by `open`, dropped by `strict`); skipped: models not "
        "converted",
    )
    listing.set_defaults(func=_list)


def _build(args: argparse.Namespace) -> int:
    from ocplace.paths import corpus_cache
    from ocplace.sim.corpus.build import build_corpus

    corpus = build_corpus(args.source, large=args.large, cutouts=tuple(args.cutouts))
    print(f"pretraining corpus: {corpus.summary()} in {corpus_cache()}")
    return 0


def _list(args: argparse.Namespace) -> int:
    import dataclasses

    from ocplace.models.offline_recipes import RenderConfig
    from ocplace.sim.corpus.build import load_corpus
    from ocplace.sim.library import load_library
    from ocplace.train.pretrain.pool import strict_drops, training_pool, validation_assets

    library, corpus = load_library(), load_corpus()
    config = dataclasses.replace(RenderConfig(), protocol=args.protocol)
    if args.show == "skipped":
        for model in corpus.models:
            if model.status == "skipped":
                print(f"{model.entry.catalogue}#{model.entry.index} {model.entry.name}: {model.reason}")
        return 0
    if args.show == "test-nouns":
        rows = [(corpus.assets[key], noun) for key, noun in sorted(strict_drops(corpus, library).items())]
    else:
        assets = (
            validation_assets(corpus, library, config)
            if args.show == "validation"
            else training_pool(library, corpus, config).assets
        )
        rows = [(asset, asset.category) for asset in assets]
    print(f"{'key':22} {'name':28} {'noun':16} extents (m)")
    for asset, noun in rows:
        print(f"{asset.name:22} {asset.human_name:28} {noun:16} {' x '.join(f'{e:.3f}' for e in asset.extents)}")
    print(f"{len(rows)} models, {len({asset.human_name for asset, _ in rows})} names")
    return 0
