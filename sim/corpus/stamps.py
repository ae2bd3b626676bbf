"""Reading Tux Paint's stamps (Debian's `tuxpaint-stamps-default`): named PNG images with alpha, one English
description each, as cut-out models of the pretraining corpus (`sim.corpus.cutout`).

Which stamps, and what each is called, was fixed from the package's folders and descriptions before any
score (docs/offline_backbone.md, "Cut-outs"): the folders of things (animals, clothes, food, hobbies,
household, medical, plants, seasonal, sports, vehicles; not symbols, signs and buildings, space, people,
cartoon characters, natural forces or weapons), PNG only (the SVGs would need a rasteriser), mirrored
copies (`*_mirror.png`) left out. A stamp is named by its description's first clause without its article
("A green apple." -> "green apple") when that is at most `MAX_NAME_WORDS` words, else by its file name.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

from ocplace.paths import inside
from ocplace.sim.corpus.catalogue import CatalogueEntry
from ocplace.sim.corpus.cutout import SIZE_CM

DEFAULT_STAMPS = Path("/usr/share/tuxpaint/stamps")
STAMPS_ENV = "OCPLACE_STAMPS_SOURCE"  # a folder laid out like Tux Paint's stamps instead of Debian's
STAMPS_INSTALL_HINT = "sudo apt-get install tuxpaint-stamps-default (Debian/Ubuntu)"
STAMPS_CATALOGUE = "tuxpaint"
STAMPS_LICENCE = "GPL-2.0-or-later (Tux Paint stamps, /usr/share/doc/tuxpaint-stamps-default/copyright)"
STAMPS_CREATOR = "Tux Paint contributors (Bill Kendrick et al.)"
STAMP_FOLDERS = (
    "animals",
    "clothes",
    "food",
    "hobbies",
    "household",
    "medical",
    "plants",
    "seasonal",
    "sports",
    "vehicles",
)
MAX_NAME_WORDS = 4
_ARTICLE = re.compile(r"^(a|an|the|some)\s+")
_CLAUSE_END = re.compile(r"[.,!?;:(]|\s[-\u2013\u2014]\s|\u2014")


def stamps_dir(source: str | os.PathLike | None = None) -> Path:
    """Where the stamps are: `source`, else `$OCPLACE_STAMPS_SOURCE`, else Debian's package folder."""
    return Path(source or os.environ.get(STAMPS_ENV) or DEFAULT_STAMPS)


def stamp_name(description: str, stem: str) -> str:
    """What pretraining calls a stamp: its description's first clause without the article, or its file name."""
    first = _CLAUSE_END.split(description.strip().lower(), maxsplit=1)[0]
    name = " ".join(_ARTICLE.sub("", first.strip()).split())
    if name and len(name.split()) <= MAX_NAME_WORDS:
        return name
    return " ".join(re.sub(r"[^a-z]+", " ", stem.lower()).split())


def _description(text: Path) -> str:
    """The first line of a stamp's `.txt` (its English description); ValueError when missing or not UTF-8."""
    try:
        return text.read_bytes().decode("utf-8").splitlines()[0].strip()
    except FileNotFoundError:
        raise ValueError("no description (.txt)") from None
    except UnicodeDecodeError as error:
        raise ValueError(f"its description is not UTF-8 ({error.reason})") from None
    except IndexError:
        raise ValueError("its description is empty") from None


def _within(source: Path, relative: str) -> Path:
    try:
        return inside(source, relative)
    except ValueError:
        raise ValueError(f"{relative} leads outside the stamps folder (a symlink?)") from None


def read_stamps(source: Path) -> tuple[list[CatalogueEntry], list[tuple[str, str]]]:
    """The usable stamps of `source` as catalogue entries (in path order; `model` is the path relative to
    `source`) and `(path, why)` for each stamp that cannot be used.

    A file that resolves outside `source` (a symlink out of the package) is refused before it is opened.
    """
    entries: list[CatalogueEntry] = []
    problems: list[tuple[str, str]] = []
    images = sorted(p for folder in STAMP_FOLDERS for p in (source / folder).rglob("*.png"))
    for image in images:
        relative = image.relative_to(source).as_posix()
        if image.stem.endswith("_mirror"):
            continue
        try:
            _within(source, relative)
            description = _description(_within(source, Path(relative).with_suffix(".txt").as_posix()))
            name = stamp_name(description, image.stem)
            if not name:
                raise ValueError(f"no name in {description!r} or its file name")
        except (ValueError, OSError) as error:
            problems.append((relative, str(error)))
            continue
        entries.append(
            CatalogueEntry(
                STAMPS_CATALOGUE, len(entries), name, relative.split("/")[0], SIZE_CM, relative, None, STAMPS_CREATOR
            )
        )
    return entries, problems
