"""The `ocplace` console script: the top layer, over the library it drives.

Each command group is a module of this package that registers its subcommands through a
`register(subparsers)` function. Command modules import heavy libraries (JAX, MuJoCo) inside
their handlers so that `ocplace --help` stays instant.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys

from ocplace import __version__
from ocplace.errors import OcplaceError

COMMAND_MODULES = (
    "ocplace.cli.assets",
    "ocplace.cli.scene",
    "ocplace.cli.generate",
    "ocplace.cli.dataset",
    "ocplace.cli.parse",
    "ocplace.cli.featurize",
    "ocplace.cli.train",
    "ocplace.cli.corpus",
    "ocplace.cli.backbone",
    "ocplace.cli.densities",
    "ocplace.cli.evaluate",
    "ocplace.cli.reproduce",
    "ocplace.cli.place",
    "ocplace.cli.export",
)


QUIET_LIBRARIES = ("trimesh", "OpenGL", "jax", "absl", "numexpr")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="ocplace", description="Object-centric, language-conditioned object placement."
    )
    parser.add_argument("--version", action="version", version=f"ocplace {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="log debug messages")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for module_name in COMMAND_MODULES:
        importlib.import_module(module_name).register(subparsers)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(levelname)s %(name)s: %(message)s",
    )
    if not args.verbose:  # their INFO lines (hundreds from trimesh in `make demo`) say nothing a user acts on
        for name in QUIET_LIBRARIES:
            logging.getLogger(name).setLevel(logging.WARNING)
    try:
        _check_output(args)
        return args.func(args) or 0
    except OcplaceError as error:
        print(f"ocplace {args.command}: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


def _check_output(args: argparse.Namespace) -> None:
    """A bad `--out` (every command names its output `out`) fails before the command does any work."""
    from ocplace.paths import check_writable

    if getattr(args, "out", None) is not None:
        check_writable(args.out)
