"""Input checks, tokens and reference normalisation shared by every parser.

Checks run before any parser sees the text, so the offline and the LLM parsers reject bad input
the same way, and the LLM never receives text that is trying to rewrite its prompt.
"""

from __future__ import annotations

import dataclasses
import re
import unicodedata

from ocplace.errors import ParseError
from ocplace.sim import language

DEFAULT_MAX_CHARS = 1000  # a four-relation instruction with long names is ~250 characters

_FORBIDDEN_CHARACTERS = set("{}<>[]=`|\\^~")
_INJECTION = re.compile(
    r"\b(ignore|disregard|forget|override)\b.{0,40}\b(instructions?|prompt|above|previous|rules)\b"
    r"|\bsystem prompt\b|\byou are now\b|\b(assistant|system)\s*:|\brespond with\b|\boutput (json|the)\b",
    re.IGNORECASE | re.DOTALL,
)
_WORD = re.compile(r"[^\W_]+(?:['\-][^\W_]+)*'?")
_PUNCTUATION = re.compile(r"[,.!?;:()\"\n]")

ARTICLES = frozenset({"a", "an", "the", "teh", "hte"})
_LEADING_DETERMINERS = frozenset({"both", "this", "that", "these", "those", "my", "your", "our"})
TABLE_WORDS = frozenset({"table", "tabletop", "desk", "workspace", "worktop", "workbench", "surface"})
_TABLE_MODIFIERS = frozenset({"whole", "entire", "empty", "work", "table"})


@dataclasses.dataclass(frozen=True)
class Token:
    text: str  # lower case; "," for a comma, "." for any hard break
    is_word: bool


def validate(instruction: object, max_chars: int = DEFAULT_MAX_CHARS) -> str:
    """The instruction, NFKC-normalised, or a ParseError saying what is wrong with it."""
    if not isinstance(instruction, str):
        raise ParseError(f"an instruction is text, got {type(instruction).__name__}")
    text = unicodedata.normalize("NFKC", instruction).replace("\u2019", "'").strip()
    if not text:
        raise ParseError(
            "the instruction is empty; say where to put the object, e.g. 'put it to the left of the red bowl'"
        )
    if len(text) > max_chars:
        raise ParseError(
            f"the instruction is {len(text)} characters long (limit {max_chars}); "
            "a placement instruction needs one sentence"
        )
    letters = [c for c in text if c.isalpha()]
    if not letters:
        raise ParseError("the instruction has no words")
    foreign = sum(not c.isascii() for c in letters)
    if foreign > 0.2 * len(letters):
        raise ParseError("the instruction does not look like English; only English instructions are supported")
    bad = sorted(_FORBIDDEN_CHARACTERS.intersection(text))
    if bad:
        raise ParseError(
            f"the instruction contains characters that do not belong in a placement instruction: {''.join(bad)!r}"
        )
    if _INJECTION.search(text):
        raise ParseError(
            "the instruction reads like an attempt to change the parser's own "
            "instructions, not like a placement instruction"
        )
    return text


def tokenize(text: str) -> list[Token]:
    """Words and breaks: `","` for commas, `"."` for sentence-level punctuation.

    Hyphenated words and possessives stay one token ("spider-man", "rubik's").
    """
    tokens: list[Token] = []
    position = 0
    lowered = text.lower()
    while position < len(lowered):
        match = _WORD.match(lowered, position)
        if match:
            tokens.append(Token(match.group(0), True))
            position = match.end()
            continue
        char = lowered[position]
        if _PUNCTUATION.match(char):
            tokens.append(Token("," if char == "," else ".", False))
        position += 1
    return tokens


def normalise_reference(words: list[str]) -> str:
    """Lower case, articles dropped anywhere, leading determiners dropped, "table" for the table."""
    kept = [w for w in words if w not in ARTICLES]
    while kept and kept[0] in _LEADING_DETERMINERS:
        kept = kept[1:]
    if kept and kept[-1] in TABLE_WORDS and all(w in _TABLE_MODIFIERS for w in kept[:-1]):
        return language.TABLE_NAME
    if kept in (["table", "top"], ["table", "surface"]):
        return language.TABLE_NAME
    return " ".join(kept)
