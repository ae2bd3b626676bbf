"""What a parser returns: `<reference, relation>` tuples and how each was obtained."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Protocol

from ocplace.sim import language, relations

PROVENANCES = ("direct", "snapped")


@dataclasses.dataclass(frozen=True)
class ParsedTuple:
    """One `<reference, relation>` pair read from an instruction."""

    reference: str  # normalised: lower case, articles stripped, "table" for the table
    relation: str  # canonical relation name (ocplace.sim.relations.RELATION_NAMES)
    relation_phrase: str  # the relation as written (offline) or as the LLM answered it
    provenance: str = "direct"  # "direct": read as a canonical relation; "snapped": by similarity
    similarity: float | None = None  # cosine similarity of the snap; None when direct
    parser: str = "offline"  # which parser produced the tuple
    fallback_reason: str | None = None  # why a parser fell back to the offline one, if it did
    disagreement: str | None = None  # how the LLM's answer and the offline parse differed, if they did

    def __post_init__(self):
        relations.relation(self.relation)
        if self.provenance not in PROVENANCES:
            raise ValueError(f"provenance must be one of {PROVENANCES}, got {self.provenance!r}")
        if not self.reference:
            raise ValueError("a parsed tuple needs a non-empty reference")

    @property
    def is_table(self) -> bool:
        return self.reference == language.TABLE_NAME


class Parser(Protocol):
    """Anything that turns an instruction into tuples or raises `ocplace.errors.ParseError`."""

    name: str

    def parse(self, instruction: str) -> list[ParsedTuple]: ...


def as_pairs(tuples: Sequence[ParsedTuple]) -> list[tuple[str, str]]:
    """`(reference, relation)` pairs, the part that accuracy is scored on."""
    return [(item.reference, item.relation) for item in tuples]


def parse_note(tuples: Sequence[ParsedTuple]) -> str | None:
    """Why a parse may not be the LLM's own answer: its fall-back reasons and disagreements, once each."""
    notes = [note for item in tuples for note in (item.fallback_reason, item.disagreement) if note]
    return "; ".join(dict.fromkeys(notes)) or None
