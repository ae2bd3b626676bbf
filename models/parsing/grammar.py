"""Relation mentions in an instruction: where each relation is and what it refers to.

An instruction is cut into clauses at sentence punctuation, commas, and conjunctions ("and",
"while", "but", ...) that introduce another relation. In a clause, a relation starts at a cue
word (a direction, a proximity word, or an unsupported relation) and runs over relation words
("to the left hand side of the"); the reference is what follows, up to the next relation, a
politeness or command word, or the end of the clause. Anything before the first relation
(polite prefix, verb, the held object's name or pronoun) is ignored, whatever its words are.
"""

from __future__ import annotations

import dataclasses

from ocplace.models.parsing import lexicon, text

_CONJUNCTIONS = frozenset({"and", "while", "whilst", "but", "yet", "plus", "also", "then"})
_REGION_EXTRAS = frozenset({"its"})
_SNAP_PREPOSITIONS = frozenset({"of", "to", "from", "than", "at", "on", "in", "by"})
_TABLE_ONLY_PREPOSITIONS = frozenset({"on", "onto", "upon", "at", "in"})


@dataclasses.dataclass
class Mention:
    """One relation as written, with its reference before resolution across clauses."""

    region: list[str]  # relation words as written ("to", "the", "left", "of", "the")
    tags: list[lexicon.Tag]
    reference: list[str]  # reference words as written; empty when none was written
    pronoun: bool = False  # the reference is "it"/"its": resolved to another mention's reference
    possessive: bool = False  # "the cup's left side"
    sentence: int = 0
    needs_snapping: bool = False  # no cue word: the relation phrase goes to the sentence encoder

    @property
    def phrase(self) -> str:
        words = list(self.region)
        while words and words[-1] in text.ARTICLES:
            words.pop()
        return " ".join(words)

    @property
    def directions(self) -> set[str]:
        return {d for tag in self.tags if tag.kind == "dir" for d in tag.directions}

    @property
    def is_proximity_only(self) -> bool:
        return not self.directions and any(tag.kind == "prox" for tag in self.tags)

    @property
    def unsupported_reason(self) -> str | None:
        return next((tag.reason for tag in self.tags if tag.kind == "unsupported"), None)

    @property
    def dangling(self) -> bool:
        """Ends in "of"/"to"/"behind" with nothing after it: "behind and to the left of the cup"."""
        if self.reference or self.pronoun or self.possessive or not self.region:
            return False
        last = self.region[-1]
        return last in lexicon.LINKERS or last in lexicon.PREPOSITION_CUES


def clauses(instruction: str) -> list[tuple[int, list[str]]]:
    """`(sentence index, words)` per clause, typos in direction words corrected."""
    pieces: list[tuple[int, list[str]]] = [(0, [])]
    for token in text.tokenize(instruction):
        sentence = pieces[-1][0]
        if not token.is_word:
            pieces.append((sentence + (token.text == "."), []))
        else:
            pieces[-1][1].append(lexicon.correct_typo(token.text))
    out: list[tuple[int, list[str]]] = []
    for sentence, words in pieces:
        for part in _split_at_conjunctions(lexicon.rewrite_viewer_phrases(words)):
            if part:
                out.append((sentence, part))
    return out


def _split_at_conjunctions(words: list[str]) -> list[list[str]]:
    """Cuts at a conjunction whose following words hold a relation cue."""
    parts: list[list[str]] = [[]]
    i = 0
    while i < len(words):
        length = _conjunction_length(words, i)
        if length and _has_cue(_segment_after(words, i + length)):
            parts.append([])
            i += length
            continue
        parts[-1].append(words[i])
        i += 1
    return parts


def _conjunction_length(words: list[str], i: int) -> int:
    if words[i : i + 3] == ["as", "well", "as"]:
        return 3
    if words[i] not in _CONJUNCTIONS:
        return 0
    length = 1
    while i + length < len(words) and words[i + length] in _CONJUNCTIONS:
        length += 1
    return length


def _segment_after(words: list[str], start: int) -> list[str]:
    end = start
    while end < len(words) and not _conjunction_length(words, end):
        end += 1
    return words[start:end]


def _has_cue(words: list[str]) -> bool:
    return any(tag.is_cue for tag in lexicon.tag_words(words))


def mentions_in(words: list[str], sentence: int) -> list[Mention]:
    """The relation mentions of one clause, left to right; [] when it holds none."""
    tags = lexicon.tag_words(words)
    scanner = _ClauseScanner(words, tags)
    found: list[Mention] = []
    start = scanner.next_relation(0)
    floor = 0
    while start is not None:
        region_end = scanner.region_end(start)
        region_start = scanner.extend_left(start, floor)
        mention = Mention(words[region_start:region_end], tags[region_start:region_end], [], sentence=sentence)
        if region_start > floor and words[region_start - 1].endswith("'s"):
            mention.reference = scanner.possessor(region_start - 1, floor)
            mention.possessive = True
        reference_end, start = scanner.reference_end(region_end)
        if not mention.possessive:
            mention.reference = _trim_reference(words[region_end:reference_end])
        mention.pronoun = "its" in mention.region or (
            bool(mention.reference) and " ".join(mention.reference) in lexicon.PRONOUN_REFERENCES
        )
        if mention.pronoun and not mention.possessive:
            mention.reference = []
        found.append(mention)
        floor = reference_end
    return found or _snapping_candidate(words, sentence)


_RELATIVE_PRONOUNS = frozenset({"that", "which", "who", "where"})


def _trim_reference(words: list[str]) -> list[str]:
    words = list(words)
    while words and (
        words[-1] in lexicon.LINKERS
        or words[-1] in _CONJUNCTIONS
        or (len(words) > 1 and words[-1] in _RELATIVE_PRONOUNS)
    ):
        words.pop()
    return words


def _snapping_candidate(words: list[str], sentence: int) -> list[Mention]:
    """A clause with no cue word but the shape "... <relation words> <preposition> the <noun>".

    The relation words go to the sentence encoder ("kitty-corner from the mug"). Clauses without
    that shape ("put it down", "thank you") hold no relation. Returns [] or one Mention.
    """
    after_held = max((i + 1 for i, w in enumerate(words) if w in lexicon.HELD_OBJECT_WORDS), default=0)
    body = words[after_held:]
    for i in range(len(body) - 1, -1, -1):
        if body[i] not in _SNAP_PREPOSITIONS:
            continue
        reference = [w for w in body[i + 1 :] if w not in text.ARTICLES]
        relation_words = body[: i + 1]
        if not reference or " ".join(reference) in lexicon.PRONOUN_REFERENCES:
            return []
        is_table = text.normalise_reference(reference) == "table"
        if is_table and all(w in _TABLE_ONLY_PREPOSITIONS or w in text.ARTICLES for w in relation_words):
            return []  # "put it on the table": where, not which part
        return [
            Mention(
                relation_words, lexicon.tag_words(relation_words), body[i + 1 :], sentence=sentence, needs_snapping=True
            )
        ]
    return []


class _ClauseScanner:
    """Finds relation regions and reference ends in one clause."""

    def __init__(self, words: list[str], tags: list[lexicon.Tag]):
        self.words = words
        self.tags = tags

    def _in_region(self, i: int) -> bool:
        tag = self.tags[i]
        return tag.is_cue or tag.kind in ("filler", "function") or self.words[i] in _REGION_EXTRAS

    def _is_linker(self, i: int) -> bool:
        return self.words[i] in lexicon.LINKERS or self.words[i] in lexicon.PREPOSITION_CUES

    def region_end(self, start: int) -> int:
        """End (exclusive) of the relation words from `start`, leaving a reference after them."""
        end = start
        while end < len(self.words) and self._in_region(end):
            end += 1
        if end == len(self.words) or self._is_linker(end - 1):
            return end
        if self.words[end] in lexicon.REFERENCE_STOPS:
            return end
        for i in range(end - 1, start - 1, -1):
            if self._is_linker(i) and any(t.is_cue for t in self.tags[start : i + 1]):
                return i + 1  # "to the right of the | left shoe"
        return end

    def _qualifies(self, start: int) -> bool:
        end = self.region_end(start)
        if end == len(self.words) or self.words[end] in lexicon.REFERENCE_STOPS:
            return True
        return self._is_linker(end - 1) or self.words[end] in lexicon.PRONOUN_REFERENCES

    def next_relation(self, begin: int) -> int | None:
        return next(
            (i for i in range(begin, len(self.words)) if self.tags[i].is_cue and self._qualifies(i)),
            None,
        )

    def extend_left(self, start: int, floor: int) -> int:
        while start > floor and (self.tags[start - 1].kind == "function" or self.words[start - 1] in _REGION_EXTRAS):
            start -= 1
        return start

    def possessor(self, index: int, floor: int) -> list[str]:
        """The noun phrase ending in the possessive at `index` ("the rubber duck's")."""
        start = index
        while start > floor and not (
            self._is_linker(start - 1)
            or self.tags[start - 1].kind == "function"
            or self.words[start - 1] in lexicon.HELD_OBJECT_WORDS
        ):
            start -= 1
        words = self.words[start : index + 1]
        words[-1] = words[-1][:-2] if words[-1].endswith("'s") else words[-1]
        return words

    def reference_end(self, begin: int) -> tuple[int, int | None]:
        """`(end of the reference from begin, start of the next relation or None)`."""
        for i in range(begin, len(self.words)):
            if self.words[i] in lexicon.REFERENCE_STOPS:
                return i, self.next_relation(i)
            if self.tags[i].is_cue and self._qualifies(i):
                return self.extend_left(i, begin), i
        return len(self.words), None
