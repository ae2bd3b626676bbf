"""Type-check ocplace with mypy (`make lint`): the packages pyproject's [tool.mypy] names, strictly; the rest is read.

The package's folders sit at the repository's root and setuptools maps them into `ocplace` (pyproject's
`package-dir`); the editable install does that with an import hook, which no type checker follows. So the map is
laid out under `build/typecheck/` as `scripts/check_layers.py` lays it out for import-linter, and mypy reads that
tree (its cache in `build/mypy_cache/`). Messages name the checkout's files. Exit status: mypy's.
"""

from __future__ import annotations

import os
import shutil
import sys
import tomllib
from pathlib import Path

from check_layers import lay_out
from mypy import api

ROOT = Path(__file__).resolve().parent.parent
TREE = ROOT / "build" / "typecheck"


def main() -> int:
    package_dirs = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-dir"]
    shutil.rmtree(TREE, ignore_errors=True)
    lay_out(ROOT, package_dirs, TREE)
    os.chdir(ROOT)  # the config's cache folder is relative to it
    stdout, stderr, status = api.run(
        ["--config-file", str(ROOT / "pyproject.toml"), "--python-executable", sys.executable]
    )
    for package, folder in sorted(package_dirs.items(), reverse=True):  # the deepest first: ocplace.sim before ocplace
        stdout = stdout.replace(str(TREE.relative_to(ROOT).joinpath(*package.split("."))) + "/", folder + "/")
    sys.stdout.write(stdout)
    sys.stderr.write(stderr)
    return status


if __name__ == "__main__":
    raise SystemExit(main())
