"""A converted object's folder that vouches for its content: every file's sha256, checked whenever it is read.

Library objects and corpus models are built into a temp folder and renamed into place, so a folder is
complete when it appears; `CHECKSUMS_FILE`, written last inside it, then lets every later read tell a
folder that was edited or damaged since (a changed mesh byte, a lost hull) from one as built.
"""

from __future__ import annotations

import json
from pathlib import Path

from ocplace.paths import file_sha256, inside
from ocplace.sim.library.records import ASSET_FILE

CHECKSUMS_FILE = "checksums.json"


def write_checksums(directory: Path) -> None:
    """Writes `CHECKSUMS_FILE`: the sha256 of every other file in `directory` (call it after the last one)."""
    sums = {p.name: file_sha256(p) for p in sorted(directory.iterdir()) if p.is_file() and p.name != CHECKSUMS_FILE}
    (directory / CHECKSUMS_FILE).write_text(json.dumps(sums, indent=1) + "\n")


def damage(directory: Path) -> str:
    """Why the folder cannot be trusted ("" when every file is as built)."""
    try:
        sums = json.loads((directory / CHECKSUMS_FILE).read_text())
    except (OSError, ValueError):
        return f"{CHECKSUMS_FILE} is missing or unreadable"
    if not isinstance(sums, dict) or ASSET_FILE not in sums:
        return f"{CHECKSUMS_FILE} is not a table of the folder's files"
    for name, digest in sums.items():
        try:
            if file_sha256(inside(directory, name)) != digest:
                return f"{name} changed since it was built"
        except (OSError, ValueError):
            return f"{name} is missing or not a file of the folder"
    return ""


def read_checked(directory: Path) -> dict:
    """The `ASSET_FILE` record of a folder whose files are as built; ValueError naming what is not."""
    problem = damage(directory)
    if problem:
        raise ValueError(f"{directory}: {problem}")
    return json.loads((directory / ASSET_FILE).read_text())
