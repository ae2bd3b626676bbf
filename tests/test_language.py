"""The instruction vocabulary and renderer (sim/language.py)."""

import itertools
import re

import numpy as np
import pytest

from ocplace.sim import language, relations
from ocplace.sim.language import ReferenceTuple


def test_vocabulary_sizes_match_design():
    assert len(language.SEEN_TABLE_PHRASES) == 9
    assert len(language.SEEN_OBJECT_PHRASES) == 8
    assert len(language.UNSEEN_PREFIXES) == 7
    assert len(language.UNSEEN_VERBS) == 8
    assert len(language.UNSEEN_PRONOUNS) == 3
    expressions = [e for group in language.UNSEEN_RELATION_EXPRESSIONS.values() for e in group]
    assert len(expressions) == len(set(expressions)) == 25


def test_every_canonical_relation_has_phrases():
    assert set(language.SEEN_TABLE_PHRASES) == set(relations.RELATION_NAMES)
    assert set(language.SEEN_OBJECT_PHRASES) == set(relations.OBJECT_RELATION_NAMES)
    assert set(language.UNSEEN_RELATION_EXPRESSIONS) == set(relations.RELATION_NAMES)


def test_unseen_expressions_never_appear_in_seen_phrases():
    seen = set(language.SEEN_TABLE_PHRASES.values()) | set(language.SEEN_OBJECT_PHRASES.values())
    for group in language.UNSEEN_RELATION_EXPRESSIONS.values():
        assert seen.isdisjoint(group)


@pytest.mark.parametrize(
    "tuples, expected",
    [
        ((ReferenceTuple("table", "back left", True),), "put it to the top left corner of the table."),
        ((ReferenceTuple("table", "middle", True),), "put it to the middle of the table."),
        ((ReferenceTuple("red bowl", "back", False),), "put it behind the red bowl."),
        (
            (ReferenceTuple("red bowl", "front", False), ReferenceTuple("rubber duck", "left", False)),
            "put it in front of the red bowl and to the left of the rubber duck.",
        ),
    ],
)
def test_seen_rendering_is_the_template(tuples, expected):
    assert language.render_instruction(tuples, "seen", np.random.default_rng(0)) == expected


def _alternatives(options) -> str:
    return "|".join(re.escape(o) for o in options)


def _unseen_pattern(count: int) -> re.Pattern:
    expressions = [e for group in language.UNSEEN_RELATION_EXPRESSIONS.values() for e in group]
    relation = f"(?P<rel{{i}}>{_alternatives(expressions)}) the (?P<ref{{i}}>[a-z' ]+?)"
    body = " and ".join(relation.format(i=i) for i in range(count))
    return re.compile(
        f"^(?:{_alternatives(language.UNSEEN_PREFIXES[1:])})?(?:{_alternatives(language.UNSEEN_VERBS)}) "
        f"(?:{_alternatives(language.UNSEEN_PRONOUNS)}) {body}\\.$"
    )


def test_unseen_instructions_match_their_template_and_tuples():
    rng = np.random.default_rng(7)
    names = ["alphabet soup can", "black shoe with green stripes", "rubik's cube", "red bowl"]
    for _ in range(300):
        count = int(rng.integers(1, 3))
        picked = rng.choice(len(names), size=count, replace=False)
        tuples = [ReferenceTuple(names[i], relations.OBJECT_RELATION_NAMES[rng.integers(8)], False) for i in picked]
        if count == 1 and rng.random() < 0.5:
            tuples = [ReferenceTuple("table", relations.RELATION_NAMES[rng.integers(9)], True)]
        instruction = language.render_instruction(tuples, "unseen", rng)
        match = _unseen_pattern(len(tuples)).match(instruction)
        assert match, instruction
        for i, item in enumerate(tuples):
            assert match[f"ref{i}"] == item.name
            assert match[f"rel{i}"] in language.unseen_expressions(item.relation, item.is_table)


def test_unseen_rendering_is_deterministic_per_seed():
    tuples = (ReferenceTuple("red bowl", "left", False),)
    first = [language.render_instruction(tuples, "unseen", np.random.default_rng(3)) for _ in range(2)]
    assert first[0] == first[1]
    many = {language.render_instruction(tuples, "unseen", np.random.default_rng(s)) for s in range(40)}
    assert len(many) > 10


def test_invalid_tuples_and_styles_are_rejected():
    with pytest.raises(ValueError, match="table only"):
        ReferenceTuple("red bowl", "middle", False)
    with pytest.raises(KeyError, match="canonical relations"):
        ReferenceTuple("red bowl", "under", False)
    with pytest.raises(ValueError, match="style"):
        language.render_instruction((ReferenceTuple("table", "left", True),), "poetic", np.random.default_rng(0))
    with pytest.raises(ValueError, match="1 or 2"):
        language.render_instruction((), "seen", np.random.default_rng(0))


def test_unseen_instruction_count_formula():
    counts = language.count_unseen_instructions(50)
    assert counts["table"] == 168 * 25
    assert counts["1obj"] == 168 * 22 * 50
    assert counts["2obj"] == 168 * (22 * 50) * (22 * 49)
    assert counts["total"] == counts["table"] + counts["1obj"] + counts["2obj"]


def test_unseen_instruction_count_matches_enumeration():
    names = ["red bowl", "blue mug", "rubber duck"]
    leads = [
        f"{p}{v} {n}"
        for p, v, n in itertools.product(language.UNSEEN_PREFIXES, language.UNSEEN_VERBS, language.UNSEEN_PRONOUNS)
    ]
    table = {
        f"{lead} {e} the table."
        for lead in leads
        for r in relations.RELATION_NAMES
        for e in language.unseen_expressions(r, True)
    }
    object_phrases = [
        f"{e} the {name}"
        for name in names
        for r in relations.OBJECT_RELATION_NAMES
        for e in language.unseen_expressions(r, False)
    ]
    one = {f"{lead} {phrase}." for lead in leads for phrase in object_phrases}
    two = {
        f"{lead} {a} and {b}."
        for lead in leads
        for a, b in itertools.product(object_phrases, object_phrases)
        if a.split(" the ")[-1] != b.split(" the ")[-1]
    }
    counts = language.count_unseen_instructions(len(names))
    assert (len(table), len(one), len(two)) == (counts["table"], counts["1obj"], counts["2obj"])


def test_seen_examples_use_only_seen_phrases_and_cover_them():
    examples = language.seen_examples()
    seen = set(language.SEEN_TABLE_PHRASES.values()) | set(language.SEEN_OBJECT_PHRASES.values())
    used = set()
    for instruction, tuples in examples:
        for item in tuples:
            phrase = language.seen_phrase(item.relation, item.is_table)
            assert f"{phrase} the {item.name}" in instruction
            used.add(phrase)
        for group in language.UNSEEN_RELATION_EXPRESSIONS.values():
            assert not any(f" {e} " in f" {instruction} " for e in group)
    assert used == seen
