"""Captions for pretraining: names, synonyms and attributes of each training object, and the table.

Several objects can share a caption ("a bowl", "something red"), so each caption records every
class it describes; the contrastive loss treats all of them as positives. Besides the library's
objects there are recoloured objects ("a blue bowl") and named primitives ("a small red cylinder"),
described here with the same fields so that they get the same kinds of captions.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from ocplace.models.backbone import PromptConfig
from ocplace.sim.corpus.selection import NOUN_GROUPS
from ocplace.vocabulary import SHAPE_WORDS

COLOUR_WORDS = (
    "red",
    "green",
    "blue",
    "yellow",
    "white",
    "black",
    "brown",
    "orange",
    "grey",
    "gray",
    "purple",
    "pink",
    "silver",
    "golden",
)
NOT_COLOURS = ("orange juice",)  # phrases whose colour word names something else
SIZE_WORDS = {"small": "small", "medium": "", "large": "large"}  # a medium primitive is just "a blue cone"
OBJECT, RECOLOURED, PRIMITIVE, TABLE = "object", "recoloured", "primitive", "table"  # kinds of class
NAME_TEMPLATES = (
    "{a} {name}",
    "the {name}",
    "{name}",
    "{a} {name} on a table",
    "a top-down photo of {a} {name}.",
    "a photo of the {name}.",
)
TABLE_CAPTIONS = (
    "a table",
    "the table",
    "table",
    "a table top",
    "a photo of the table.",
    "a top-down photo of a table.",
    "objects on a table",
    "the whole table",
)


@dataclasses.dataclass(frozen=True)
class ObjectDescription:
    """What captions may say about one object (fields of the library's `ObjectAsset`); `kind` says
    whether it is a library object as rendered, a recoloured one or a primitive."""

    name: str
    human_name: str
    synonyms: tuple[str, ...]
    category: str
    kind: str = OBJECT

    @classmethod
    def of(cls, asset) -> ObjectDescription:
        return cls(asset.name, asset.human_name, tuple(asset.synonyms), asset.category)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(dict.fromkeys(" ".join(n.lower().split()) for n in (self.human_name, *self.synonyms)))

    @property
    def colours(self) -> tuple[str, ...]:
        """Colour words its names use ("black and white bowl" -> black, white)."""
        words = {word for name in self.names for word in colour_words(name)}
        return tuple(colour for colour in COLOUR_WORDS if colour in words)


def colour_words(name: str) -> list[str]:
    """The words of `name` that are colours ("orange juice carton" has none)."""
    for phrase in NOT_COLOURS:
        name = name.replace(phrase, phrase.replace(" ", "_"))
    return [word for word in name.split() if word in COLOUR_WORDS]


def with_colour(name: str, colour: str) -> str:
    """`name` with its colour words (and the "and" between them) replaced by `colour` in front:
    "black and white bowl" -> "blue bowl", "ketchup" -> "blue ketchup"."""
    words = name.split()
    colours = set(colour_words(name))
    between = {
        i for i in range(1, len(words) - 1) if words[i] == "and" and words[i - 1] in colours and words[i + 1] in colours
    }
    kept = [w for i, w in enumerate(words) if i not in between and w not in colours]
    return " ".join([colour, *kept])


def recoloured(obj: ObjectDescription, colour: str) -> ObjectDescription:
    """`obj` painted `colour` all over: each name with `colour` instead of its own colours, and the
    names that have no colour word as they are (a blue alphabet soup can is still an alphabet soup can)."""
    names = [with_colour(name, colour) for name in obj.names] + [n for n in obj.names if not colour_words(n)]
    return ObjectDescription(f"{obj.name}:{colour}", names[0], tuple(names[1:]), obj.category, RECOLOURED)


def primitive_description(name: str, shape: str, size: str, colour: str) -> ObjectDescription:
    """A `colour` primitive `shape` of `size` ("small", "medium", "large"), named `name:colour`:
    "small blue cylinder", "blue cylinder", "small cylinder" and "blue <synonym>"."""
    word, *synonyms = SHAPE_WORDS[shape]
    size_word = SIZE_WORDS[size]
    sized = (
        [f"{size_word} {colour} {word}", f"{colour} {word}", f"{size_word} {word}"]
        if size_word
        else [f"{colour} {word}"]
    )
    names = sized + [f"{colour} {synonym}" for synonym in synonyms]
    return ObjectDescription(f"{name}:{colour}", names[0], tuple(names[1:]), word, PRIMITIVE)


def article(phrase: str) -> str:
    return "an" if phrase[:1] in "aeiou" else "a"


def object_captions(obj: ObjectDescription, prompt: PromptConfig) -> list[str]:
    """Every caption of `obj`: the grounding prompt and other templates around each name, its
    category, and its colours with and without the category."""
    captions = []
    for name in obj.names:
        # As the recipes were pretrained: a caption bank in other words would be another backbone under one key.
        captions.append(prompt.text_for(name, plural=False))
        captions += [t.format(a=article(name), name=name) for t in NAME_TEMPLATES]
    category = obj.category.lower()
    captions += [f"{article(category)} {category}", f"a photo of {article(category)} {category}."]
    for colour in obj.colours:
        captions += [
            f"{article(colour)} {colour} {category}",
            f"a photo of {article(colour)} {colour} {category}.",
            f"something {colour}",
            f"{article(colour)} {colour} object",
        ]
    return list(dict.fromkeys(captions))


def table_captions(prompt: PromptConfig) -> list[str]:
    return list(dict.fromkeys((prompt.table_text, *TABLE_CAPTIONS)))


@dataclasses.dataclass(frozen=True)
class CaptionBank:
    """Captions of `K` classes: the `N` objects in order, the table (class `N`), then the extras
    (recoloured objects, primitives) if any.

    texts: `C` distinct captions; applies: bool `(C, K)`, caption c describes class k;
    own: per class, the caption indices generated for it (sampled for its images);
    kinds: per class, `OBJECT`, `TABLE`, `RECOLOURED` or `PRIMITIVE`;
    groups: per class, its category's group (`sim.corpus.selection.NOUN_GROUPS`: wall plugs, switches and
    sockets one group; a primitive's shape), which group-balanced sampling draws first.
    """

    class_names: tuple[str, ...]
    texts: tuple[str, ...]
    applies: np.ndarray
    own: tuple[np.ndarray, ...]
    kinds: tuple[str, ...]
    groups: tuple[str, ...]

    @property
    def table_class(self) -> int:
        return self.kinds.index(TABLE)

    def sample(self, rng: np.random.Generator, labels: np.ndarray) -> np.ndarray:
        """int32 `(B,)`: one caption index per label, uniform over the class's own captions."""
        return np.array([self.own[k][rng.integers(len(self.own[k]))] for k in labels], np.int32)


def build_caption_bank(
    objects: Sequence[ObjectDescription],
    prompt: PromptConfig = PromptConfig(),
    extras: Sequence[ObjectDescription] = (),
) -> CaptionBank:
    """The bank of `objects`, the table and `extras`, in that order (the table keeps class `N`, so a
    bank with extras labels the library's objects and the table as one without)."""
    per_class = (
        [object_captions(obj, prompt) for obj in objects]
        + [table_captions(prompt)]
        + [object_captions(obj, prompt) for obj in extras]
    )
    texts = tuple(dict.fromkeys(caption for captions in per_class for caption in captions))
    index = {text: i for i, text in enumerate(texts)}
    applies = np.zeros((len(texts), len(per_class)), bool)
    own = []
    for k, captions in enumerate(per_class):
        rows = np.array([index[c] for c in captions], np.int32)
        applies[rows, k] = True
        own.append(rows)
    names = tuple(obj.name for obj in objects) + ("table",) + tuple(obj.name for obj in extras)
    kinds = tuple(obj.kind for obj in objects) + (TABLE,) + tuple(obj.kind for obj in extras)
    groups = tuple(NOUN_GROUPS.get(obj.category, obj.category) for obj in objects)
    groups += (TABLE,) + tuple(NOUN_GROUPS.get(obj.category, obj.category) for obj in extras)
    return CaptionBank(names, texts, applies, tuple(own), kinds, groups)
