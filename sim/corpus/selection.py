"""Which catalogue models the pretraining corpus holds: a size and geometry rule, never a rule by name,
then the two protocols (`open`, `strict`) and the validation split of held-out names.

The rule was fixed from the catalogue's own numbers before any test object was looked at:
tabletop things (longest side <= 40 cm), not paper-thin (smallest side >= 4 mm: a bank note or a
ruler is a texture on a sliver), and not heavier than `max_faces` triangles (what the CPU renderer
draws at the benchmark's pace). `strict` then drops every model whose name holds a noun that names a
test object (docs/offline_backbone.md lists the dropped models); `open` keeps them, as CLIP's data
holds teddy bears and bread while the task's training data does not.
"""

from __future__ import annotations

import dataclasses
import hashlib
import re
from collections.abc import Iterable, Sequence

from ocplace.sim.corpus.catalogue import CatalogueEntry

PROTOCOLS = ("open", "strict")
_WORD = re.compile(r"[a-z0-9']+")
# Test-category words the library's names do not spell out but a catalogue may use for the same thing.
STRICT_EXTRA_NOUNS = ("espresso kettle", "kettle", "pen holder", "organiser", "organizer")


@dataclasses.dataclass(frozen=True)
class SelectionRule:
    """A model is kept when all three hold (catalogue sizes in cm; faces after loading)."""

    max_side_cm: float = 40.0
    min_side_cm: float = 0.4
    max_faces: int = 60_000

    def size_problem(self, entry: CatalogueEntry) -> str:
        """Why `entry`'s catalogue size rules it out ("" when it does not)."""
        sizes = entry.size_cm
        if not all(0.0 < s < 1e4 for s in sizes):  # NaN fails too
            return f"size {sizes} cm is missing, zero or absurd"
        if max(sizes) > self.max_side_cm:
            return f"longest side {max(sizes):g} cm > {self.max_side_cm:g} cm"
        if min(sizes) < self.min_side_cm:
            return f"smallest side {min(sizes):g} cm < {self.min_side_cm:g} cm (too thin)"
        return ""

    def faces_problem(self, faces: int) -> str:
        return f"{faces} faces > {self.max_faces}" if faces > self.max_faces else ""


def words(text: str) -> str:
    """Lower-case words separated by single spaces, padded: `" salt shaker "`."""
    return " " + " ".join(_WORD.findall(text.lower())) + " "


def head_noun(name: str) -> str:
    """The noun a name is about: its last word before a "with" or a comma ("bowl with fruits" -> bowl)."""
    core = re.split(r",| with ", name.lower())[0]
    found = words(core).split()
    return found[-1] if found else ""


def test_nouns(test_objects: Iterable) -> tuple[str, ...]:
    """Every category, name, synonym and their head nouns of the test objects (library assets outside the
    training split), plus `STRICT_EXTRA_NOUNS`."""
    nouns = set(STRICT_EXTRA_NOUNS)
    for asset in test_objects:
        for phrase in (asset.category, asset.human_name, *asset.synonyms):
            nouns |= {words(phrase).strip(), head_noun(phrase)}
    return tuple(sorted(noun for noun in nouns if noun))


def names_test_noun(name: str, nouns: Sequence[str]) -> str:
    """The first of `nouns` that `name` holds as whole words (a plural -s allowed), "" if none."""
    padded = words(name)
    for noun in nouns:
        if f" {noun} " in padded or f" {noun}s " in padded:
            return noun
    return ""


def is_validation(name: str, share: float, seed: int = 0) -> bool:
    """Whether the name `name` is held out for validation: a seeded hash, the same on every machine."""
    digest = hashlib.sha256(f"ocplace-corpus-validation:{seed}:{words(name).strip()}".encode()).digest()
    return int.from_bytes(digest[:8], "big") / 2**64 < share
