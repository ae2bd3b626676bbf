"""The offline parser: a lexicon-and-grammar reader with sentence-encoder snapping. No network.

Mentions found by `grammar` are resolved across clauses:
- "its"/"it" refer to the nearest written reference ("next to the cup, on its left side");
- a relation ending in "of"/"behind" with nothing after it shares the next reference
  ("behind and to the left of the mug");
- a proximity-only mention ("next to the cup", "beside the mug") takes its side from a
  neighbouring mention without a reference ("..., on the left"); alone it is an error;
- a direction without a reference means the table ("put it on the left");
- two relations on the same reference on different axes make a corner ("left of and behind
  the mug" is back left); opposite ones contradict ("to the left and right of the mug" is an
  error, not the table's left and the mug's right).
"""

from __future__ import annotations

from collections.abc import Callable

from ocplace.errors import ParseError
from ocplace.models.parsing import grammar, lexicon, text
from ocplace.models.parsing.config import GrammarConfig
from ocplace.models.parsing.snapping import Snapper
from ocplace.models.parsing.types import ParsedTuple
from ocplace.sim import language, relations

_HORIZONTAL = (lexicon.LEFT, lexicon.RIGHT)
_DEPTH = (lexicon.BACK, lexicon.FRONT)
_OPPOSITE = {
    lexicon.LEFT: lexicon.RIGHT,
    lexicon.RIGHT: lexicon.LEFT,
    lexicon.BACK: lexicon.FRONT,
    lexicon.FRONT: lexicon.BACK,
}


class OfflineParser:
    """Parses instructions without a network; loads the sentence encoder only when it must snap."""

    def __init__(self, config: GrammarConfig, snapper_factory: Callable[[], Snapper], name: str = "offline"):
        self.config = config
        self.name = name
        self._snapper_factory = snapper_factory
        self._snapper: Snapper | None = None

    @property
    def snapper(self) -> Snapper:
        if self._snapper is None:
            self._snapper = self._snapper_factory()
        return self._snapper

    def parse(self, instruction: str) -> list[ParsedTuple]:
        cleaned = text.validate(instruction, self.config.max_chars)
        mentions = [
            mention for sentence, words in grammar.clauses(cleaned) for mention in grammar.mentions_in(words, sentence)
        ]
        if not mentions:
            raise ParseError(
                f"no spatial relation found in {cleaned[:80]!r}; say where, e.g. "
                "'put it to the left of the red bowl' or 'in the top left corner of the table'"
            )
        items = [self._relation_of(m) for m in _resolve(mentions)]
        return _merge_same_reference(items, self.name)

    def _relation_of(self, mention: grammar.Mention) -> tuple[str, str, str, float | None]:
        """`(reference, canonical relation, phrase, similarity or None)` of a resolved mention."""
        reference = text.normalise_reference(mention.reference)
        phrase = mention.phrase
        if not reference:
            raise ParseError(
                f"{phrase!r} {' '.join(mention.reference)!r} names no object; "
                "say which object, e.g. 'to the left of the red bowl'"
            )
        if mention.needs_snapping or self.config.relation_source == "encoder":
            snap = self.snapper.snap(phrase) if mention.needs_snapping else self.snapper.nearest(phrase)
            relation, similarity = snap.relation, snap.similarity
        else:
            relation, similarity = _relation_from_directions(mention.directions, phrase), None
        if reference != language.TABLE_NAME and not relations.relation(relation).applies_to_objects:
            raise ParseError(
                f"{phrase!r} {reference!r}: the middle is a region of the table only; "
                "for an object say left, right, in front of or behind"
            )
        return reference, relation, phrase, similarity


# Direction words that, as a whole relation from an LLM, may mean proximity or height rather than a side.
_LONE_AMBIGUOUS = frozenset(
    "near nearer nearest far farther further furthest farthest top upper bottom lower beyond past".split()
)


def relation_of_phrase(phrase: str) -> str | None:
    """The canonical relation a bare relation phrase names by the lexicon ("upper right corner": back
    right, "near side": front), or None when a word of it is not a direction, filler or function word."""
    words = lexicon.rewrite_viewer_phrases([lexicon.correct_typo(t.text) for t in text.tokenize(phrase) if t.is_word])
    tags = lexicon.tag_words(words)
    if not words or any(tag.kind not in ("dir", "filler", "function") for tag in tags):
        return None
    sides = [word for word, tag in zip(words, tags) if tag.kind == "dir" and word not in _LONE_AMBIGUOUS]
    if not sides and not any(tag.kind == "filler" for tag in tags):
        return None  # an LLM's "near" means beside, its "top" may mean on top ("near side" is a side): snap it
    try:
        return _relation_from_directions({d for tag in tags for d in tag.directions}, phrase)
    except ParseError:
        return None


def _relation_from_directions(directions: set[str], phrase: str) -> str:
    horizontal = [d for d in _HORIZONTAL if d in directions]
    depth = [d for d in _DEPTH if d in directions]
    if len(horizontal) > 1 or len(depth) > 1:
        raise ParseError(f"{phrase!r} names opposite directions at once")
    if depth and horizontal:
        return f"{depth[0]} {horizontal[0]}"
    if depth or horizontal:
        return (depth or horizontal)[0]
    if lexicon.MIDDLE in directions:
        return "middle"
    raise ParseError(
        f"{phrase!r} says no direction; say left, right, in front of, behind, a corner, or the middle of the table"
    )


def _resolve(mentions: list[grammar.Mention]) -> list[grammar.Mention]:
    """Mentions with every reference filled in (the table where none was written)."""
    for mention in mentions:
        reason = mention.unsupported_reason
        if reason:
            raise ParseError(
                f"{mention.phrase!r} is a {reason} relation, which is not one of the "
                "nine; use left, right, in front of, behind, a corner or the middle"
            )
    _resolve_pronouns(mentions)
    _share_dangling_references(mentions)
    _give_sides_to_proximity(mentions)
    resolved = []
    for mention in mentions:
        if mention.is_proximity_only:
            if any(
                other.reference == mention.reference and other.directions for other in mentions if other is not mention
            ):
                continue
            raise ParseError(
                f"{mention.phrase!r} {' '.join(mention.reference)!r} does not say on which side; add e.g. 'on its left'"
            )
        if not mention.reference:
            mention.reference = [language.TABLE_NAME]
        resolved.extend(_split_conjoined_references(mention))
    return resolved


def _resolve_pronouns(mentions: list[grammar.Mention]) -> None:
    for index, mention in enumerate(mentions):
        if not mention.pronoun:
            continue
        before = [m.reference for m in mentions[:index] if m.reference]
        after = [m.reference for m in mentions[index + 1 :] if m.reference and not m.pronoun]
        antecedent = before[-1] if before else after[0] if after else None
        if antecedent is None:
            raise ParseError(
                f"{mention.phrase!r} refers to 'it', but the instruction names no "
                "object for it to stand for (the held object cannot be a reference)"
            )
        mention.reference = list(antecedent)


def _share_dangling_references(mentions: list[grammar.Mention]) -> None:
    for index in range(len(mentions) - 1, -1, -1):
        mention = mentions[index]
        if not mention.dangling:
            continue
        following = next((m for m in mentions[index + 1 :] if m.reference), None)
        if following is None:
            raise ParseError(f"{mention.phrase!r} is not followed by an object or 'the table'")
        mention.reference = list(following.reference)


def _give_sides_to_proximity(mentions: list[grammar.Mention]) -> None:
    """Pairs each referenceless direction with a neighbouring reference-bearing mention.

    A neighbouring proximity mention is preferred ("beside the mug, on the left"); else the
    next mention when it names the opposite side ("to the left and right of the mug": one
    reference, so that the contradiction is reported); else the previous mention when it
    repeats the direction or is on the other axis; else the next mention when it is on the
    other axis ("to the front and to the right of the block").
    """
    for index, mention in enumerate(mentions):
        if mention.reference or not mention.directions or mention.needs_snapping:
            continue
        neighbours = [mentions[j] for j in (index - 1, index + 1) if 0 <= j < len(mentions)]
        partner = next((m for m in neighbours if m.is_proximity_only and m.reference), None)
        following = mentions[index + 1] if index + 1 < len(mentions) else None
        if (
            partner is None
            and following is not None
            and following.reference
            and following.sentence == mention.sentence
            and _opposite(mention.directions, following.directions)
        ):
            partner = following
        previous = mentions[index - 1] if index > 0 else None
        if (
            partner is None
            and previous is not None
            and previous.reference
            and previous.sentence == mention.sentence
            and mention.directions <= previous.directions
        ):
            partner = previous  # "in front of the cup, towards me" repeats the relation
        if (
            partner is None
            and previous is not None
            and previous.reference
            and previous.sentence == mention.sentence
            and _axes(mention.directions)
            and _axes(previous.directions).isdisjoint(_axes(mention.directions))
        ):
            partner = previous  # "to the front of the tray, slightly to the left": a corner
        if (
            partner is None
            and following is not None
            and following.reference
            and following.sentence == mention.sentence
            and _axes(mention.directions)
            and _axes(following.directions).isdisjoint(_axes(mention.directions))
        ):
            partner = following
        if partner is not None:
            mention.reference = list(partner.reference)


def _opposite(first: set[str], second: set[str]) -> bool:
    return any(_OPPOSITE.get(direction) in second for direction in first)


def _axes(directions: set[str]) -> set[str]:
    return {("x" if d in _HORIZONTAL else "y") for d in directions if d != lexicon.MIDDLE}


def _split_conjoined_references(mention: grammar.Mention) -> list[grammar.Mention]:
    """ "both the lemon and the banana" -> one mention per reference, same relation."""
    words = list(mention.reference)
    both = words[:1] == ["both"]
    if both:
        words = words[1:]
    cuts = [
        i
        for i, w in enumerate(words)
        if w == "and" and (both or (i + 1 < len(words) and words[i + 1] in text.ARTICLES))
    ]
    if not cuts:
        return [mention]
    pieces, start = [], 0
    for cut in cuts + [len(words)]:
        pieces.append(words[start:cut])
        start = cut + 1
    return [_with_reference(mention, piece) for piece in pieces if piece]


def _with_reference(mention: grammar.Mention, reference: list[str]) -> grammar.Mention:
    copy = grammar.Mention(
        mention.region, mention.tags, reference, sentence=mention.sentence, needs_snapping=mention.needs_snapping
    )
    return copy


def _merge_same_reference(items, parser_name: str) -> list[ParsedTuple]:
    """One tuple per (reference, relation); orthogonal relations on one reference make a corner."""
    merged: dict[str, list] = {}
    for reference, relation, phrase, similarity in items:
        if reference not in merged:
            merged[reference] = [relation, phrase, similarity]
            continue
        previous = merged[reference]
        combined = _combine(previous[0], relation)
        if combined is None:
            raise ParseError(
                f"the relations {previous[0]!r} and {relation!r} on {reference!r} contradict: "
                "they cannot both hold. Keep one of them; two relations on different axes "
                "make a corner ('behind and to the left of the mug')"
            )
        previous[0] = combined
        previous[1] = f"{previous[1]}; {phrase}"
    return [
        ParsedTuple(reference, relation, phrase, "direct" if similarity is None else "snapped", similarity, parser_name)
        for reference, (relation, phrase, similarity) in merged.items()
    ]


def _combine(first: str, second: str) -> str | None:
    """ "left" + "back" -> "back left"; equal relations stay; anything else conflicts."""
    if first == second:
        return first
    parts = set(first.split()) | set(second.split())
    if lexicon.MIDDLE in parts:
        return None
    horizontal = [d for d in _HORIZONTAL if d in parts]
    depth = [d for d in _DEPTH if d in parts]
    if len(horizontal) == 1 and len(depth) == 1:
        return f"{depth[0]} {horizontal[0]}"
    return None
