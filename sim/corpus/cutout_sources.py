"""The sources of cut-outs (`RenderConfig.cutouts`): where each one's images are, how they are read, whose they are."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

from ocplace.sim.corpus import emoji, stamps
from ocplace.sim.corpus.catalogue import CatalogueEntry


@dataclasses.dataclass(frozen=True)
class CutoutSource:
    name: str  # as `RenderConfig.cutouts` and `ocplace corpus build --cutouts` spell it
    catalogue: str  # the catalogue (key prefix) of its models
    licence: str
    install_hint: str
    locate: Callable[[bool], Path]  # its folder; fetched first when asked for (True) and fetchable
    read: Callable[[Path], tuple[list[CatalogueEntry], list[tuple[str, str]]]]


CUTOUT_SOURCES = {
    source.name: source
    for source in (
        CutoutSource(
            "stamps",
            stamps.STAMPS_CATALOGUE,
            stamps.STAMPS_LICENCE,
            stamps.STAMPS_INSTALL_HINT,
            lambda asked: stamps.stamps_dir(),
            stamps.read_stamps,
        ),
        CutoutSource(
            "emoji",
            emoji.EMOJI_CATALOGUE,
            emoji.EMOJI_LICENCE,
            emoji.EMOJI_INSTALL_HINT,
            lambda asked: emoji.fetch_emoji() if asked else emoji.emoji_dir(),
            emoji.read_emoji,
        ),
    )
}
CUTOUT_CATALOGUES = frozenset(source.catalogue for source in CUTOUT_SOURCES.values())
