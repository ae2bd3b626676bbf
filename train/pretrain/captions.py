"""Captions for pretraining: names, synonyms and attributes of each training object, and the table.

Several objects can share a caption ("a bowl", "something red"), so each caption records every
class it describes; the contrastive loss treats all of them as positives.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from ocplace.models.backbone import PromptConfig

COLOUR_WORDS = ("red", "green", "blue", "yellow", "white", "black", "brown", "orange", "grey", "gray",
                "purple", "pink", "silver", "golden")
NAME_TEMPLATES = ("{a} {name}", "the {name}", "{name}", "{a} {name} on a table", "a top-down photo of {a} {name}.",
                  "a photo of the {name}.")
TABLE_CAPTIONS = ("a table", "the table", "table", "a table top", "a photo of the table.",
                  "a top-down photo of a table.", "objects on a table", "the whole table")


@dataclasses.dataclass(frozen=True)
class ObjectDescription:
    """What captions may say about one object (fields of the library's `ObjectAsset`)."""

    name: str
    human_name: str
    synonyms: tuple[str, ...]
    category: str

    @classmethod
    def of(cls, asset) -> ObjectDescription:
        return cls(asset.name, asset.human_name, tuple(asset.synonyms), asset.category)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(dict.fromkeys(" ".join(n.lower().split()) for n in (self.human_name, *self.synonyms)))

    @property
    def colours(self) -> tuple[str, ...]:
        """Colour words its names use ("black and white bowl" -> black, white)."""
        words = {word for name in self.names for word in name.split()}
        return tuple(colour for colour in COLOUR_WORDS if colour in words)


def article(phrase: str) -> str:
    return "an" if phrase[:1] in "aeiou" else "a"


def object_captions(obj: ObjectDescription, prompt: PromptConfig) -> list[str]:
    """Every caption of `obj`: the grounding prompt and other templates around each name, its
    category, and its colours with and without the category."""
    captions = []
    for name in obj.names:
        captions.append(prompt.text_for(name))
        captions += [t.format(a=article(name), name=name) for t in NAME_TEMPLATES]
    category = obj.category.lower()
    captions += [f"{article(category)} {category}", f"a photo of {article(category)} {category}."]
    for colour in obj.colours:
        captions += [f"{article(colour)} {colour} {category}", f"a photo of {article(colour)} {colour} {category}.",
                     f"something {colour}", f"{article(colour)} {colour} object"]
    return list(dict.fromkeys(captions))


def table_captions(prompt: PromptConfig) -> list[str]:
    return list(dict.fromkeys((prompt.table_text, *TABLE_CAPTIONS)))


@dataclasses.dataclass(frozen=True)
class CaptionBank:
    """Captions of `K` classes: the objects in order, then the table (class `K - 1`).

    texts: `C` distinct captions; applies: bool `(C, K)`, caption c describes class k;
    own: per class, the caption indices generated for it (sampled for its images).
    """

    class_names: tuple[str, ...]
    texts: tuple[str, ...]
    applies: np.ndarray
    own: tuple[np.ndarray, ...]

    @property
    def table_class(self) -> int:
        return len(self.class_names) - 1

    def sample(self, rng: np.random.Generator, labels: np.ndarray) -> np.ndarray:
        """int32 `(B,)`: one caption index per label, uniform over the class's own captions."""
        return np.array([self.own[k][rng.integers(len(self.own[k]))] for k in labels], np.int32)


def build_caption_bank(objects: Sequence[ObjectDescription], prompt: PromptConfig = PromptConfig()) -> CaptionBank:
    per_class = [object_captions(obj, prompt) for obj in objects] + [table_captions(prompt)]
    texts = tuple(dict.fromkeys(caption for captions in per_class for caption in captions))
    index = {text: i for i, text in enumerate(texts)}
    applies = np.zeros((len(texts), len(per_class)), bool)
    own = []
    for k, captions in enumerate(per_class):
        rows = np.array([index[c] for c in captions], np.int32)
        applies[rows, k] = True
        own.append(rows)
    return CaptionBank(tuple(obj.name for obj in objects) + ("table",), texts, applies, tuple(own))
