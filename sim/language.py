"""Instruction vocabulary and rendering: the single source of truth (docs/design.md#relations-and-instructions).

Seen instructions use one fixed phrase per (relation, reference kind); unseen instructions change
everything around the reference names: a polite prefix, a verb, a pronoun for the held object,
and relation expressions that never appear in seen instructions. Parsers draw their few-shot
examples from the seen side only, so unseen instructions stay unseen.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from ocplace.sim import relations

TABLE_NAME = "table"
STYLES = ("seen", "unseen")

# Seen phrases: one per relation and reference kind ("middle" is a table region only).
SEEN_TABLE_PHRASES: dict[str, str] = {
    "left": "to the left part of",
    "right": "to the right part of",
    "back": "to the top part of",
    "front": "to the bottom part of",
    "middle": "to the middle of",
    "back left": "to the top left corner of",
    "back right": "to the top right corner of",
    "front left": "to the bottom left corner of",
    "front right": "to the bottom right corner of",
}
SEEN_OBJECT_PHRASES: dict[str, str] = {
    "left": "to the left of",
    "right": "to the right of",
    "back": "behind",
    "front": "in front of",
    "back left": "to the back left of",
    "back right": "to the back right of",
    "front left": "to the front left of",
    "front right": "to the front right of",
}

SEEN_TEMPLATES: tuple[str, ...] = (
    "put it {rel0} the {ref0}.",
    "put it {rel0} the {ref0} and {rel1} the {ref1}.",
)
UNSEEN_TEMPLATES: tuple[str, ...] = (
    "{prefix}{verb} {pronoun} {rel0} the {ref0}.",
    "{prefix}{verb} {pronoun} {rel0} the {ref0} and {rel1} the {ref1}.",
)

# Unseen vocabulary. A prefix is written with its trailing space so that "" means no prefix.
UNSEEN_PREFIXES: tuple[str, ...] = (
    "",
    "please ",
    "could you please ",
    "can you ",
    "would you kindly ",
    "now ",
    "robot, ",
)
UNSEEN_VERBS: tuple[str, ...] = ("put", "place", "drop", "move", "set", "lay", "position", "leave")
UNSEEN_PRONOUNS: tuple[str, ...] = ("it", "the thing", "the object")
UNSEEN_RELATION_EXPRESSIONS: dict[str, tuple[str, ...]] = {
    "left": ("on the left hand side of", "on the left side of", "left to"),
    "right": ("on the right hand side of", "on the right side of", "right to"),
    "front": ("in the front of", "before", "at the front of", "to the near side of"),
    "back": ("at the back of", "in the rear of", "at the rear of", "to the far side of"),
    "front left": ("to the left front corner of", "to the lower left corner of"),
    "front right": ("to the right front corner of", "to the lower right corner of"),
    "back left": ("to the left rear corner of", "to the upper left corner of"),
    "back right": ("to the right rear corner of", "to the upper right corner of"),
    "middle": ("in the middle of", "at the center of", "in the center of"),
}


@dataclasses.dataclass(frozen=True)
class ReferenceTuple:
    """One `<reference, relation>` pair as the generator knows it."""

    name: str  # the reference's human name, or TABLE_NAME
    relation: str  # canonical relation name
    is_table: bool

    def __post_init__(self):
        relations.relation(self.relation)  # raises KeyError naming the valid relations
        if not self.is_table and not relations.relation(self.relation).applies_to_objects:
            raise ValueError(f"relation {self.relation!r} applies to the table only")
        if self.is_table and self.name != TABLE_NAME:
            raise ValueError(f"a table reference is named {TABLE_NAME!r}, not {self.name!r}")


def seen_phrase(relation: str, is_table: bool) -> str:
    """The one seen phrase for `relation` used with the table or with an object."""
    phrases = SEEN_TABLE_PHRASES if is_table else SEEN_OBJECT_PHRASES
    if relation not in phrases:
        raise ValueError(f"no seen phrase for {relation!r} with {'the table' if is_table else 'an object'}")
    return phrases[relation]


def unseen_expressions(relation: str, is_table: bool) -> tuple[str, ...]:
    """Unseen expressions usable for `relation`; "middle" only with the table."""
    if not is_table and not relations.relation(relation).applies_to_objects:
        return ()
    return UNSEEN_RELATION_EXPRESSIONS[relations.relation(relation).name]


def render_instruction(tuples: Sequence[ReferenceTuple], style: str, rng: np.random.Generator) -> str:
    """The instruction text for 1 or 2 reference tuples in the "seen" or "unseen" style.

    Seen instructions are fully determined by the tuples; unseen ones draw a prefix, a verb, a
    pronoun and one expression per tuple from `rng`.
    """
    if style not in STYLES:
        raise ValueError(f"unknown style {style!r}; use one of {STYLES}")
    if not 1 <= len(tuples) <= 2:
        raise ValueError(f"templates hold 1 or 2 references, got {len(tuples)}")
    fields: dict[str, str] = {}
    for index, item in enumerate(tuples):
        fields[f"ref{index}"] = item.name
        if style == "seen":
            fields[f"rel{index}"] = seen_phrase(item.relation, item.is_table)
        else:
            fields[f"rel{index}"] = _choose(rng, unseen_expressions(item.relation, item.is_table))
    if style == "seen":
        return SEEN_TEMPLATES[len(tuples) - 1].format(**fields)
    fields["prefix"] = _choose(rng, UNSEEN_PREFIXES)
    fields["verb"] = _choose(rng, UNSEEN_VERBS)
    fields["pronoun"] = _choose(rng, UNSEEN_PRONOUNS)
    return UNSEEN_TEMPLATES[len(tuples) - 1].format(**fields)


def _choose(rng: np.random.Generator, options: Sequence[str]) -> str:
    return options[int(rng.integers(len(options)))]


def count_unseen_instructions(num_object_names: int) -> dict[str, int]:
    """How many distinct unseen instruction strings the vocabulary can produce, per level.

    With `L = 7 * 8 * 3 = 168` leads (prefix, verb, pronoun), 25 expressions for the table and
    22 for objects (no "middle"), and `n` distinct object names:
    table: `168 * 25`; 1obj: `168 * 22 * n`; 2obj: `168 * (22 * n) * (22 * (n - 1))` (two
    different objects, in order). Distinct vocabulary entries and distinct names give distinct
    strings, so these counts are exact. For a single scene, pass its number of objects.
    """
    if num_object_names < 0:
        raise ValueError(f"num_object_names must be >= 0, got {num_object_names}")
    leads = len(UNSEEN_PREFIXES) * len(UNSEEN_VERBS) * len(UNSEEN_PRONOUNS)
    table_options = sum(len(unseen_expressions(name, True)) for name in relations.RELATION_NAMES)
    object_options = sum(len(unseen_expressions(name, False)) for name in relations.OBJECT_RELATION_NAMES)
    n = num_object_names
    counts = {
        "table": leads * table_options,
        "1obj": leads * object_options * n,
        "2obj": leads * (object_options * n) * (object_options * max(n - 1, 0)),
    }
    counts["total"] = sum(counts.values())
    return counts


def seen_examples() -> tuple[tuple[str, tuple[ReferenceTuple, ...]], ...]:
    """Seen-template instructions with their tuples, for few-shot prompts.

    Every seen table phrase and object phrase appears once, with placeholder object names that
    are not in any library, so prompts teach the format without leaking the test vocabulary.
    """
    names = ("green block", "coffee mug", "toy robot", "paper box")
    singles = [ReferenceTuple(TABLE_NAME, name, True) for name in relations.RELATION_NAMES]
    singles += [
        ReferenceTuple(names[i % len(names)], name, False) for i, name in enumerate(relations.OBJECT_RELATION_NAMES)
    ]
    pairs = [
        (ReferenceTuple(names[0], "left", False), ReferenceTuple(names[1], "back", False)),
        (ReferenceTuple(names[2], "front right", False), ReferenceTuple(names[3], "back left", False)),
    ]
    rng = np.random.default_rng(0)  # seen rendering draws nothing; the rng is only a formality
    groups = [(item,) for item in singles] + pairs
    return tuple((render_instruction(group, "seen", rng), tuple(group)) for group in groups)
