"""Run the import-linter contracts of pyproject.toml on the package as it is installed.

The top-level folders (`sim/`, `models/`, ...) are the `ocplace.*` subpackages by setuptools'
`package-dir` map, which import-linter cannot follow: it walks one folder per root package. So
the map is laid out in a temporary folder (the sources copied into `ocplace/<name>/`) and the
contracts run there, from inside that folder: import-linter puts the working directory first on
`sys.path`, where the checkout's own `ocplace/` would hide the laid-out one. Every import counts, at
module level and inside functions alike.
"""

import contextlib
import shutil
import sys
import tempfile
import tomllib
from pathlib import Path

from importlinter.cli import lint_imports

ROOT = Path(__file__).resolve().parent.parent


def lay_out(package_dirs: dict[str, str], into: Path) -> None:
    for package, folder in sorted(package_dirs.items(), key=lambda item: item[0].count(".")):
        target = into.joinpath(*package.split("."))
        shutil.copytree(ROOT / folder, target, ignore=shutil.ignore_patterns("__pycache__", "*.json", "*.txt"))


def main() -> int:
    config = ROOT / "pyproject.toml"
    package_dirs = tomllib.loads(config.read_text())["tool"]["setuptools"]["package-dir"]
    with tempfile.TemporaryDirectory() as view, contextlib.chdir(view):
        lay_out(package_dirs, Path(view))
        return lint_imports(config_filename=str(config), no_cache=True)


if __name__ == "__main__":
    sys.exit(main())
