"""English spatial vocabulary, and tagging of words in context.

The word lists describe how English speakers name directions on a table seen from the front
(+y away from the viewer): "rear", "far", "upper" and "north" mean back; "near", "lower",
"bottom", "south" mean front. They are general English, not the generator's phrase list; words
outside them reach the sentence-encoder snapping instead.
"""

from __future__ import annotations

import dataclasses

LEFT, RIGHT, BACK, FRONT, MIDDLE = "left", "right", "back", "front", "middle"

_DIRECTION_WORDS: dict[str, tuple[str, ...]] = {}
for _words, _direction in (
    ("left lefthand leftward leftwards leftmost west western westward westwards", (LEFT,)),
    ("right righthand rightward rightwards rightmost east eastern eastward eastwards", (RIGHT,)),
    (
        "back behind rear rearward rearwards rearmost hind top upper uppermost topmost north northern "
        "northward northwards far farther further furthest farthest beyond past backside",
        (BACK,),
    ),
    (
        "front before bottom lower lowermost bottommost south southern southward southwards near "
        "nearer nearest fore frontal",
        (FRONT,),
    ),
    ("middle center centre central centered centred mid midpoint midway halfway centermost centremost", (MIDDLE,)),
    ("northwest topleft", (BACK, LEFT)),
    ("northeast topright", (BACK, RIGHT)),
    ("southwest bottomleft", (FRONT, LEFT)),
    ("southeast bottomright", (FRONT, RIGHT)),
):
    for _word in _words.split():
        _DIRECTION_WORDS[_word] = _direction

PROXIMITY_WORDS = frozenset(
    "next beside besides by near close nearby closeby alongside adjacent neighbouring neighboring against".split()
)
# Relations that exist in English but are not among the nine: a clear error, never a guess.
UNSUPPORTED_WORDS: dict[str, str] = {
    **dict.fromkeys("above over atop".split(), "vertical ('above', 'on top of')"),
    **dict.fromkeys("below under underneath beneath".split(), "vertical ('under', 'below')"),
    **dict.fromkeys("inside into within".split(), "containment ('inside', 'into')"),
    **dict.fromkeys("between among amongst".split(), "'between'"),
    **dict.fromkeys("around surrounding".split(), "'around'"),
}
FILLERS = frozenset(
    "side sides hand handed part parts corner corners edge edges end ends half area region section "
    "portion zone quadrant border margin flank direction".split()
)
FUNCTION_WORDS = frozenset(
    "to of at on in the a an teh hte from than and just slightly directly immediately somewhat bit "
    "little very diagonally toward towards more most exactly straight squarely immediate there "
    "here up down".split()
)
LINKERS = frozenset("of to the a an teh hte from than".split())
PREPOSITION_CUES = frozenset("behind before beside besides by near alongside beyond past".split())
PRONOUN_REFERENCES = frozenset({"it", "its", "them", "this", "that", "one", "it's"})
HELD_OBJECT_WORDS = frozenset({"it", "this", "that", "thing", "object", "item", "one", "piece"})
# A reference ends where the speaker turns back to the command or to politeness.
REFERENCE_STOPS = frozenset(
    "please pls plz thanks thank kindly if i you we goes go should must needs is are was will would belongs".split()
)
_VIEWER_WORDS = ("me", "you", "us", "camera", "viewer", "observer")
_INTENSIFIED_BY_RIGHT = frozenset(
    "behind before in at on next beside by near above below under over against alongside between "
    "there here away up down onto into inside close".split()
)
_DIRECTION_TYPO_TARGETS = (
    "left",
    "right",
    "front",
    "behind",
    "middle",
    "center",
    "centre",
    "corner",
    "rear",
    "back",
    "side",
    "hand",
)


@dataclasses.dataclass(frozen=True)
class Tag:
    """What one word does in its sentence."""

    kind: str  # "dir", "prox", "unsupported", "filler", "function", "other"
    directions: tuple[str, ...] = ()
    reason: str = ""  # for "unsupported"

    @property
    def is_cue(self) -> bool:
        return self.kind in ("dir", "prox", "unsupported")


def rewrite_viewer_phrases(words: list[str]) -> list[str]:
    """Replaces "closer to me", "towards the camera", "away from you"... with one direction word.

    Directions relative to the viewer are front (towards) and back (away).
    """
    out: list[str] = []
    i = 0
    while i < len(words):
        for length, direction in _viewer_match(words, i):
            out.append(direction)
            i += length
            break
        else:
            out.append(words[i])
            i += 1
    return out


def _viewer_match(words: list[str], i: int):
    def viewer_at(j: int) -> int:
        if j < len(words) and words[j] in _VIEWER_WORDS:
            return 1
        if j + 1 < len(words) and words[j] == "the" and words[j + 1] in _VIEWER_WORDS:
            return 2
        return 0

    word = words[i]
    if word in ("toward", "towards") or (
        word in ("closer", "nearer", "nearest") and i + 1 < len(words) and words[i + 1] == "to"
    ):
        start = i + 1 if word in ("toward", "towards") else i + 2
        if viewer_at(start):
            yield start - i + viewer_at(start), "front"
    if word in ("away", "far", "farther", "further", "farthest", "furthest"):
        j = i + 1
        if j < len(words) and words[j] == "away":
            j += 1
        if j < len(words) and words[j] == "from" and viewer_at(j + 1):
            yield j + 1 - i + viewer_at(j + 1), "back"


def correct_typo(word: str) -> str:
    """A misspelt direction word corrected ("lfet" -> "left", "behnid" -> "behind"), else `word`.

    A doubled letter; or, for words of five letters or more, one edit with the same first
    letter; four-letter words only by swapping two neighbours, so "black" never becomes "back".
    """
    if word in _DIRECTION_WORDS or word in FUNCTION_WORDS or word in FILLERS or len(word) < 4:
        return word
    undoubled = "".join(c for i, c in enumerate(word) if i == 0 or c != word[i - 1])
    if undoubled in _DIRECTION_TYPO_TARGETS:
        return undoubled  # "lefft", "behiind"
    for target in _DIRECTION_TYPO_TARGETS:
        if len(target) >= 5 and word[0] == target[0] and _within_one_edit(word, target):
            return target
        if len(target) == 4 and len(word) == 4 and _is_transposition(word, target):
            return target
    return word


def _is_transposition(word: str, target: str) -> bool:
    diffs = [i for i in range(len(word)) if word[i] != target[i]]
    return (
        len(diffs) == 2
        and diffs[1] == diffs[0] + 1
        and word[diffs[0]] == target[diffs[1]]
        and word[diffs[1]] == target[diffs[0]]
    )


def _within_one_edit(word: str, target: str) -> bool:
    if abs(len(word) - len(target)) > 1 or word == target:
        return False
    if len(word) == len(target):
        diffs = sum(a != b for a, b in zip(word, target))
        return diffs == 1 or _is_transposition(word, target)
    short, long = sorted((word, target), key=len)
    return any(long[:i] + long[i + 1 :] == short for i in range(len(long)))


def tag_words(words: list[str]) -> list[Tag]:
    """One Tag per word; context decides the ambiguous ones ("right behind", "near side")."""
    return [_tag_at(words, i) for i in range(len(words))]


def _tag_at(words: list[str], i: int) -> Tag:
    word = words[i]
    following = words[i + 1] if i + 1 < len(words) else None
    preceding = words[i - 1] if i > 0 else None
    parts = word.split("-")
    if len(parts) > 1 and all(p in _DIRECTION_WORDS or p in FILLERS for p in parts):
        directions = tuple(d for p in parts for d in _DIRECTION_WORDS.get(p, ()))
        return Tag("dir", directions) if directions else Tag("filler")
    if word == "right" and following in _INTENSIFIED_BY_RIGHT:
        return Tag("function")
    if word in ("far", "farther", "further", "furthest", "farthest", "near", "nearer", "nearest"):
        return _tag_distance_word(word, preceding, following, words[i + 2 : i + 4])
    if word in ("side", "edge") and preceding in ("the", "a") and following == "of":
        return Tag("prox")  # "at the side of the mug": beside it, side still unsaid
    if word == "close":
        return Tag("prox") if following in ("to", "by") else Tag("other")
    if word == "next":
        return Tag("prox") if following == "to" else Tag("other")
    if word == "top" and preceding == "on" and following == "of":
        return Tag("unsupported", reason=UNSUPPORTED_WORDS["atop"])
    if word == "over" and following in ("to", "there", "here", "towards", "toward"):
        return Tag("function")  # "move it over to the left"
    if word == "over" and following in ("on", "at", "in") and any(w in _DIRECTION_WORDS for w in words[i + 2 : i + 5]):
        return Tag("function")  # "over on the right side of the mug": where, not above
    if word in UNSUPPORTED_WORDS:
        return Tag("unsupported", reason=UNSUPPORTED_WORDS[word])
    if word in _DIRECTION_WORDS:
        return Tag("dir", _DIRECTION_WORDS[word])
    if word in PROXIMITY_WORDS:
        return Tag("prox")
    if word in FILLERS:
        return Tag("filler")
    if word in FUNCTION_WORDS:
        return Tag("function")
    return Tag("other")


def _tag_distance_word(word: str, preceding: str | None, following: str | None, later: list[str]) -> Tag:
    """ "far left" (intensifier), "far from" (distance), "near the cup" (proximity), "near side",
    "the far right corner" (a corner has two directions: far is the back one)."""
    is_near = word.startswith("near")
    if following in _DIRECTION_WORDS and following not in ("far", "near", "before", "behind"):
        if set(_DIRECTION_WORDS[following]) <= {LEFT, RIGHT} and {"corner", "corners"} & set(later):
            return Tag("dir", (FRONT,) if is_near else (BACK,))
        return Tag("function")
    if following in ("from", "away"):
        return Tag("unsupported", reason="distance ('far from')")
    if is_near and following not in FILLERS and following is not None and preceding not in ("the", "its"):
        return Tag("prox")
    return Tag("dir", (FRONT,) if is_near else (BACK,))
