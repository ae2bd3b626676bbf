"""Check that docs/architecture.md names only files that exist and flags that the CLI has (issue 61, item 6).

A path is any `folder/file.py` in the document, read from the repository's root or from one of the package's
folders (`baselines/common.py` is `models/baselines/common.py`); a flag is any `--name` in it, looked up among
the options of every `ocplace` subcommand and of the tools the document quotes (ruff's, pip's).
"""

import argparse
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PATH = re.compile(r"(?<![\w./<-])((?:[a-z_]+/)+[a-z_0-9]+\.(?:py|md|toml|json))\b")
FLAG = re.compile(r"(?<![\w-])(--[a-z][a-z0-9-]+)")


def cli_flags() -> set[str]:
    from ocplace.cli import build_parser

    flags: set[str] = set()
    parsers = [build_parser()]
    while parsers:
        parser = parsers.pop()
        for action in parser._actions:
            flags.update(action.option_strings)
            if isinstance(action, argparse._SubParsersAction):
                parsers.extend(action.choices.values())
    return flags


def problems(document: Path) -> list[str]:
    text = document.read_text()
    folders = [ROOT, *(ROOT / folder for folder in ("ocplace", "sim", "models", "train", "eval", "methods"))]
    found = [
        f"{name}: no such file"
        for name in sorted(set(PATH.findall(text)))
        if not any((folder / name).exists() for folder in folders)
    ]
    known = cli_flags() | {"--check", "--no-deps", "--root"}  # ruff's, pip's and check_layers.py's
    found += [f"{flag}: no ocplace command has it" for flag in sorted(set(FLAG.findall(text))) if flag not in known]
    return found


def main() -> int:
    document = ROOT / "docs" / "architecture.md"
    found = problems(document)
    for problem in found:
        print(f"{document.relative_to(ROOT)}: {problem}")
    print(f"docs/architecture.md: {len(found)} stale names")
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())
