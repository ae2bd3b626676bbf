"""Snapping a relation phrase to the nearest canonical relation by text-embedding similarity.

Targets are the canonical names and the seen phrases only (never the unseen expressions, which
stay a test). A phrase snaps when its best similarity is high enough and clearly above the
second-best relation; otherwise it is an unknown relation, not a guess.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from ocplace.errors import ParseError
from ocplace.models.parsing.encoder import TextEncoder
from ocplace.sim import language, relations

_SAME_PHRASE = 0.995  # cosine similarity of a phrase with itself, up to float error


@dataclasses.dataclass(frozen=True)
class Snap:
    relation: str
    similarity: float  # cosine similarity to the relation's closest target phrase
    margin: float  # best minus second-best relation's similarity


def target_phrases() -> tuple[tuple[str, str], ...]:
    """`(canonical relation, phrase)` pairs the encoder compares against."""
    pairs = [(name, name) for name in relations.RELATION_NAMES]
    pairs += list(language.SEEN_TABLE_PHRASES.items())
    pairs += list(language.SEEN_OBJECT_PHRASES.items())
    return tuple(pairs)


class Snapper:
    """Holds the target embeddings, computed once, and snaps phrases against them."""

    def __init__(self, encode_texts: TextEncoder, min_similarity: float, min_margin: float):
        self._encode_texts = encode_texts
        self.min_similarity = min_similarity
        self.min_margin = min_margin
        targets = target_phrases()
        self._target_relation = np.array([relations.relation_index(name) for name, _ in targets], dtype=np.int32)
        self._target_embeddings = encode_texts([phrase for _, phrase in targets])  # (P, D)
        encode_texts([targets[0][1]])  # compiles the one-phrase shape now, not on the first snap

    def relation_scores(self, phrases: Sequence[str]) -> np.ndarray:
        """`(len(phrases), 9)` best cosine similarity per canonical relation."""
        similarity = self._encode_texts(phrases) @ self._target_embeddings.T  # (n, P)
        scores = np.full((len(phrases), len(relations.RELATIONS)), -np.inf)
        for index in range(len(relations.RELATIONS)):
            columns = self._target_relation == index
            scores[:, index] = similarity[:, columns].max(axis=1)
        return scores

    def nearest(self, phrase: str) -> Snap:
        """The closest canonical relation, whatever the similarity."""
        scores = self.relation_scores([phrase])[0]
        order = np.argsort(scores)[::-1]
        return Snap(
            relations.RELATION_NAMES[order[0]], float(scores[order[0]]), float(scores[order[0]] - scores[order[1]])
        )

    def snap(self, phrase: str) -> Snap:
        """The canonical relation `phrase` means, or ParseError when no relation is close."""
        best = self.nearest(phrase)
        if best.similarity >= _SAME_PHRASE:
            return best  # a target phrase itself, however close its neighbours are
        if best.similarity < self.min_similarity or best.margin < self.min_margin:
            raise ParseError(
                f"unknown relation {phrase!r} (closest: {best.relation!r}, similarity "
                f"{best.similarity:.2f}, margin {best.margin:.2f}); say left, right, in front of, "
                "behind, one of the four corners, or the middle of the table"
            )
        return best
