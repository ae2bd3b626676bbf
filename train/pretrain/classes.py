"""The classes pretraining images are labelled with, and the rule that keeps unseen names out.

Classes `0 .. N-1` are the pool's objects as rendered and class `N` the table, exactly as in a bank
without extras; after them come the recoloured objects ("ketchup:blue") and the primitives
("primitive_cylinder_small:blue"), one class per (arena body, colour term).

No class may be captioned with an unseen object's name: a recoloured white bowl would be "a
yellow bowl", which is an unseen object, so an (object, colour) pair any of whose captions
mentions a name or synonym of a non-seen object is left out, and is never rendered either.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Sequence

from ocplace.models.backbone import PromptConfig
from ocplace.models.offline_recipes import RenderConfig
from ocplace.sim.primitives import primitive_set
from ocplace.train.pretrain.captions import (
    CaptionBank,
    ObjectDescription,
    build_caption_bank,
    object_captions,
    primitive_description,
    recoloured,
)


@dataclasses.dataclass(frozen=True)
class ExtraClass:
    """A recoloured object or a primitive: its captions, the arena body it labels, its colour term."""

    description: ObjectDescription
    body: str
    colour: str


@dataclasses.dataclass(frozen=True)
class PretrainClasses:
    """Every class of a pretraining run, in label order: `objects`, the table, `extras`."""

    objects: tuple[ObjectDescription, ...]
    extras: tuple[ExtraClass, ...]

    @property
    def table(self) -> int:
        return len(self.objects)

    def label(self, body: str, colour: str = "") -> int:
        """The class of `body` as rendered (`colour` "") or painted `colour`; KeyError if none."""
        return self._labels[(body, colour)]

    def colours_of(self, body: str) -> tuple[str, ...]:
        """The colour terms `body` may be painted in (those with a class)."""
        return tuple(extra.colour for extra in self.extras if extra.body == body)

    def bodies(self, kind: str) -> tuple[str, ...]:
        """The arena bodies of the extras of `kind` (`RECOLOURED` or `PRIMITIVE`), in class order."""
        return tuple(dict.fromkeys(extra.body for extra in self.extras if extra.description.kind == kind))

    @functools.cached_property
    def _labels(self) -> dict[tuple[str, str], int]:
        labels = {(obj.name, ""): k for k, obj in enumerate(self.objects)}
        return labels | {(extra.body, extra.colour): self.table + 1 + j for j, extra in enumerate(self.extras)}


def _padded_words(text: str) -> str:
    return f" {' '.join(text.lower().replace('.', ' ').replace(',', ' ').split())} "


def mentions(caption: str, phrase: str) -> bool:
    """Whether `phrase` occurs in `caption` as whole words ("a yellow bowl." mentions "yellow bowl")."""
    return _padded_words(phrase) in _padded_words(caption)


def unseen_names(library) -> tuple[str, ...]:
    """Names and synonyms of every object outside the training split (unseen, unseen_cat, ...)."""
    assets = [asset for asset in library.objects.values() if asset.split != "seen"]
    return tuple(sorted({" ".join(n.lower().split()) for a in assets for n in (a.human_name, *a.synonyms)}))


def leaks(description: ObjectDescription, forbidden: tuple[str, ...], prompt: PromptConfig = PromptConfig()) -> bool:
    """Whether any caption of `description` `mentions` a `forbidden` name."""
    captions = [_padded_words(caption) for caption in object_captions(description, prompt)]
    names = [_padded_words(name) for name in forbidden]
    return any(name in caption for name in names for caption in captions)


def pretraining_classes(library, assets: Sequence, config: RenderConfig) -> PretrainClasses:
    """The classes of the pool's `assets` under `config`: recolourings to each of `config.colours`
    other than the object's own, then each primitive in each colour, minus any that `leaks` (unless
    `config.colour_captions` is `open`)."""
    forbidden = () if config.colour_captions == "open" else unseen_names(library)
    descriptions = tuple(ObjectDescription.of(asset) for asset in assets)
    extras = [
        ExtraClass(recoloured(obj, colour), obj.name, colour)
        for obj in descriptions
        for colour in config.colours
        if colour not in obj.colours
    ]
    if config.primitives_per_scene > 0:
        extras += [
            ExtraClass(primitive_description(p.name, p.shape, p.size, colour), p.name, colour)
            for p in primitive_set(config.primitive_shapes, config.primitive_widths)
            for colour in config.colours
        ]
    return PretrainClasses(descriptions, tuple(e for e in extras if not leaks(e.description, forbidden)))


def caption_bank(classes: PretrainClasses, prompt: PromptConfig = PromptConfig()) -> CaptionBank:
    return build_caption_bank(classes.objects, prompt, [extra.description for extra in classes.extras])
