"""Type-check ocplace with mypy (`make lint`): every file of the library, and perf/ and scripts/; the levels per
package are pyproject's [tool.mypy] (strict for methods/, eval/, experiments/, configs/; mypy's default elsewhere).

The package's folders sit at the repository's root and setuptools maps them into `ocplace` (pyproject's
`package-dir`); the editable install does that with an import hook, which no type checker follows. So the map is
laid out under `build/typecheck/` as `scripts/check_layers.py` lays it out for import-linter, and mypy reads that
tree (its cache in `build/mypy_cache/`). Messages name the checkout's files. Exit status: mypy's.
"""

from __future__ import annotations

import os
import re
import shutil
import sys
import tomllib
from pathlib import Path

from check_layers import lay_out
from mypy import api

ROOT = Path(__file__).resolve().parent.parent
TREE = ROOT / "build" / "typecheck"
EXTRA_FOLDERS = ("perf", "scripts")  # scripts beside the library, checked at mypy's default level


def main() -> int:
    package_dirs = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-dir"]
    shutil.rmtree(TREE, ignore_errors=True)
    lay_out(ROOT, package_dirs, TREE)
    os.chdir(ROOT)  # the config's cache folder is relative to it
    library = sorted(str(path.relative_to(TREE)) for path in TREE.rglob("*.py"))
    targets = [str(TREE / "ocplace"), *EXTRA_FOLDERS]  # files, not the config's `packages`: mypy takes one kind
    stdout, stderr, status = api.run(
        ["--config-file", str(ROOT / "pyproject.toml"), "--python-executable", sys.executable, *targets]
    )
    checked = library_files_checked(stdout)
    for package, folder in sorted(package_dirs.items(), reverse=True):  # the deepest first: ocplace.sim before ocplace
        stdout = stdout.replace(str(TREE.relative_to(ROOT).joinpath(*package.split("."))) + "/", folder + "/")
    sys.stdout.write(stdout)
    sys.stderr.write(stderr)
    print(f"type-checked {checked} of {len(library)} library files, and perf/ and scripts/")
    return status


def library_files_checked(report: str) -> int:
    """How many of the library's files mypy read, from its summary line (which counts perf/ and scripts/ too)."""
    found = re.search(r"(?:in|checked) (\d+) source files?", report)
    extra = sum(len(list((ROOT / folder).glob("*.py"))) for folder in EXTRA_FOLDERS)
    return int(found[1]) - extra if found else 0


if __name__ == "__main__":
    raise SystemExit(main())
