"""The layer contracts of pyproject.toml, run by scripts/check_layers.py, hold and catch upward imports."""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
CHECK = ROOT / "scripts" / "check_layers.py"


@pytest.fixture
def checkout(tmp_path):
    """A copy of the package sources and pyproject.toml that a test may break."""
    for folder in ("ocplace", "sim", "models", "train", "eval", "methods", "experiments", "configs", "assets"):
        shutil.copytree(ROOT / folder, tmp_path / folder, ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(ROOT / "pyproject.toml", tmp_path / "pyproject.toml")
    return tmp_path


def _check(root: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, CHECK, "--root", root], capture_output=True, text=True, timeout=300)


def test_the_layers_hold(checkout):
    result = _check(checkout)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "0 broken" in result.stdout


def test_an_upward_import_inside_a_function_breaks_the_layers(checkout):
    (checkout / "sim" / "upward.py").write_text("def load():\n    from ocplace.eval import api\n\n    return api\n")
    result = _check(checkout)
    assert result.returncode != 0
    assert "ocplace.sim.upward -> ocplace.eval.api" in result.stdout


@pytest.mark.parametrize(("sibling", "module"), [("eval", "train.runner"), ("train", "eval.harness")])
def test_eval_and_train_importing_each_other_breaks_the_layers(checkout, sibling, module):
    """Scoring never trains and training never scores: the siblings share a layer, independent."""
    (checkout / sibling / "reach.py").write_text(f"import ocplace.{module}\n")
    result = _check(checkout)
    assert result.returncode != 0
    assert f"ocplace.{sibling}.reach -> ocplace.{module}" in result.stdout


def test_where_to_change_what_names_files_of_the_tree():
    """Every file or folder the "Where to change what" table of docs/architecture.md tells a reader to edit exists;
    `<row>` stands for some row folder of `methods/`."""
    import re

    text = (ROOT / "docs" / "architecture.md").read_text()
    table = text[text.index("## Where to change what") :].split("\n\n")[1]
    edits = [line.split(" | ")[1] for line in table.splitlines()[2:]]
    named = {path for cell in edits for path in re.findall(r"`([\w./<>-]+/[\w.<>-]*)`", cell)}
    rows = [folder.name for folder in (ROOT / "methods").iterdir() if (folder / "method.py").is_file()]
    assert len(named) > 10 and rows
    missing = [
        path
        for path in sorted(named)
        if not any((ROOT / path.replace("<row>", row)).exists() for row in (rows if "<row>" in path else [""]))
    ]
    assert missing == []


def test_no_module_imports_itself_back_through_others(tmp_path):
    """Issue 61: no import circle, at module level or inside a function; one added is caught, naming its modules
    (`scripts/check_layers.py` prints them and fails)."""
    sys.path.insert(0, str(ROOT / "scripts"))
    try:
        import check_layers
    finally:
        sys.path.pop(0)
    assert check_layers.import_circles(ROOT) == []
    shutil.copytree(ROOT / "models", tmp_path / "models", ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copytree(ROOT / "ocplace", tmp_path / "ocplace", ignore=shutil.ignore_patterns("__pycache__"))
    for folder in ("sim", "train", "eval", "methods", "experiments", "configs", "assets"):
        (tmp_path / folder).mkdir()
    shutil.copy(ROOT / "pyproject.toml", tmp_path / "pyproject.toml")
    (tmp_path / "models" / "circle_a.py").write_text("from ocplace.models import circle_b\n")
    (tmp_path / "models" / "circle_b.py").write_text("def late():\n    from ocplace.models.circle_a import x\n")
    assert check_layers.import_circles(tmp_path) == [["ocplace.models.circle_a", "ocplace.models.circle_b"]]


def test_architecture_names_only_files_and_flags_that_exist(tmp_path):
    """Issue 61, item 6: docs/architecture.md drifted from the code; `make lint` now checks every file path and
    flag it names (scripts/check_docs.py), and catches a stale one."""
    sys.path.insert(0, str(ROOT / "scripts"))
    try:
        import check_docs
    finally:
        sys.path.pop(0)
    assert check_docs.problems(ROOT / "docs" / "architecture.md") == []
    stale = tmp_path / "stale.md"
    stale.write_text("The rows live in `methods/ours.py`; run `ocplace reproduce --scale demo --frobnicate`.\n")
    assert check_docs.problems(stale) == ["methods/ours.py: no such file", "--frobnicate: no ocplace command has it"]


def test_the_cli_holds_no_function_another_module_imports():
    """Issue 61, item 4: the CLI parses and prints; what a test, a script or the library calls lives in a library
    layer. Only the option parsing itself (`ocplace.cli.options`, the `--set` texts scripts take too) and the entry
    points are imported from it."""
    import ast
    import importlib
    import inspect

    allowed = {"main", "build_parser"}
    found = []
    for path in sorted(ROOT.rglob("*.py")):
        relative = path.relative_to(ROOT)
        if relative.parts[0] in (".venv", "build", "ocplace") and relative.parts[:2] != ("ocplace", "runtime"):
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("ocplace.cli."):
                if node.module == "ocplace.cli.options":
                    continue
                module = importlib.import_module(node.module)
                found += [
                    f"{relative}: {node.module}.{alias.name}"
                    for alias in node.names
                    if alias.name not in allowed and inspect.isfunction(getattr(module, alias.name, None))
                ]
    assert found == []
