"""Type-check ocplace with mypy (`make lint`): the packages pyproject's [tool.mypy] names, strictly; the rest is read.

The package's folders sit at the repository's root and setuptools maps them into `ocplace` (pyproject's
`package-dir`); the editable install does that with an import hook, which no type checker follows. So the
mapping is laid out as links under `build/typecheck/ocplace`, and mypy reads that tree. Exit status: mypy's.
"""

from __future__ import annotations

import os
import sys
import tomllib
from pathlib import Path

from mypy import api

ROOT = Path(__file__).resolve().parent.parent
TREE = ROOT / "build" / "typecheck"


def package_dirs(root: Path) -> dict[str, str]:
    """pyproject's `package-dir`: package name -> folder."""
    return tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]["package-dir"]


def package_tree(root: Path, tree: Path) -> Path:
    """`tree/ocplace`, a tree of links to the folders and files pyproject's `package-dir` maps into `ocplace`."""
    for package, folder in sorted(package_dirs(root).items()):
        target = tree.joinpath(*package.split("."))
        if package.count(".") == 0:  # the top package: link its files, so that its subpackages can be links too
            target.mkdir(parents=True, exist_ok=True)
            for path in (root / folder).iterdir():
                _link(target / path.name, path)
        else:
            _link(target, root / folder)
    return tree / "ocplace"


def _link(link: Path, target: Path) -> None:
    if link.is_symlink() and link.resolve() == target.resolve():
        return
    if link.is_symlink():
        link.unlink()
    link.symlink_to(target)


def main() -> int:
    package_tree(ROOT, TREE)
    os.chdir(ROOT)  # the config's cache folder is relative to it
    stdout, stderr, status = api.run(
        ["--config-file", str(ROOT / "pyproject.toml"), "--python-executable", sys.executable]
    )
    for package, folder in sorted(package_dirs(ROOT).items(), reverse=True):  # messages name the real files
        stdout = stdout.replace(str(Path("build", "typecheck", *package.split("."))) + "/", folder + "/")
    sys.stdout.write(stdout)
    sys.stderr.write(stderr)
    return status


if __name__ == "__main__":
    raise SystemExit(main())
