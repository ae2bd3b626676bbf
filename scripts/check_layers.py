"""Run the import-linter contracts of pyproject.toml on the package as it is installed.

The top-level folders (`sim/`, `models/`, ...) are the `ocplace.*` subpackages by setuptools'
`package-dir` map, which import-linter cannot follow: it walks one folder per root package. So
the map is laid out in a temporary folder (the sources copied into `ocplace/<name>/`) and the
contracts run there, from inside that folder: import-linter puts the working directory first on
`sys.path`, where the checkout's own `ocplace/` would hide the laid-out one. Every import counts, at
module level and inside functions alike.
"""

import argparse
import contextlib
import shutil
import sys
import tempfile
import tomllib
from pathlib import Path

from importlinter.cli import lint_imports

ROOT = Path(__file__).resolve().parent.parent


def lay_out(root: Path, package_dirs: dict[str, str], into: Path) -> None:
    for package, folder in sorted(package_dirs.items(), key=lambda item: item[0].count(".")):
        target = into.joinpath(*package.split("."))
        shutil.copytree(root / folder, target, ignore=shutil.ignore_patterns("__pycache__", "*.json", "*.txt"))


def check(root: Path) -> int:
    """0 when every contract of `root`/pyproject.toml holds for the sources under `root`."""
    config = root / "pyproject.toml"
    package_dirs = tomllib.loads(config.read_text())["tool"]["setuptools"]["package-dir"]
    with tempfile.TemporaryDirectory() as view, contextlib.chdir(view):
        lay_out(root, package_dirs, Path(view))
        return lint_imports(config_filename=str(config), no_cache=True)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, default=ROOT, help="checkout to check (default: this one)")
    return check(parser.parse_args().root.resolve())


if __name__ == "__main__":
    sys.exit(main())
