"""Run the import-linter contracts of pyproject.toml on the package as it is installed, then look for import
circles.

The top-level folders (`sim/`, `models/`, ...) are the `ocplace.*` subpackages by setuptools'
`package-dir` map, which import-linter cannot follow: it walks one folder per root package. So
the map is laid out in a temporary folder (the sources copied into `ocplace/<name>/`) and the
contracts run there, from inside that folder: import-linter puts the working directory first on
`sys.path`, where the checkout's own `ocplace/` would hide the laid-out one. Every import counts, at
module level and inside functions alike.

Circles: any two modules that import each other, directly or through others, at module level or inside a function
(import-linter's layers allow them within a layer). Found with Tarjan's algorithm on the `ocplace.*` imports of
every file; none is allowed (docs/architecture.md).
"""

import argparse
import ast
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


def modules_of(root: Path, package_dirs: dict[str, str]) -> dict[str, Path]:
    """Every `ocplace.*` module of the checkout by dotted name, through the package-dir map."""
    nested = sorted(package_dirs, key=lambda package: -package.count("."))
    modules = {}
    for package, folder in package_dirs.items():
        for path in sorted((root / folder).rglob("*.py")):
            parts = [part for part in path.relative_to(root / folder).with_suffix("").parts if part != "__init__"]
            name = ".".join([package, *parts])
            if next(p for p in nested if name == p or name.startswith(p + ".")) == package:
                modules[name] = path
    return modules


def imports_of(path: Path, modules: dict[str, Path]) -> set[str]:
    """The `ocplace.*` modules `path` imports anywhere in it (a `from X import name` of a submodule counts it)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").startswith("ocplace"):
            found |= {
                f"{node.module}.{a.name}" if f"{node.module}.{a.name}" in modules else node.module for a in node.names
            }
        elif isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names if alias.name.startswith("ocplace")}
    return {name for name in found if name in modules}


def import_circles(root: Path) -> list[list[str]]:
    """Each group of modules that import one another in a circle (strongly connected, more than one)."""
    package_dirs = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]["package-dir"]
    modules = modules_of(root, package_dirs)
    graph = {name: imports_of(path, modules) - {name} for name, path in modules.items()}
    order: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    circles = []
    for start in graph:
        if start in order:
            continue
        work = [(start, iter(sorted(graph[start])))]
        order[start] = low[start] = len(order)
        stack.append(start)
        while work:  # Tarjan's algorithm without recursion
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in order:
                    order[child] = low[child] = len(order)
                    stack.append(child)
                    work.append((child, iter(sorted(graph[child]))))
                elif child in stack:
                    low[node] = min(low[node], order[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == order[node]:
                group = []
                while True:
                    member = stack.pop()
                    group.append(member)
                    if member == node:
                        break
                if len(group) > 1:
                    circles.append(sorted(group))
    return circles


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, default=ROOT, help="checkout to check (default: this one)")
    root = parser.parse_args().root.resolve()
    status = check(root)
    circles = import_circles(root)
    for circle in circles:
        print("import circle: " + " <-> ".join(circle))
    print(f"Import circles: {len(circles)}")
    return status or (1 if circles else 0)


if __name__ == "__main__":
    sys.exit(main())
