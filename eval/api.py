"""The contract between the evaluation harness and a method: what it sees of a scene, what it returns.

A `Method` places the held object in dataset scenes (the registered ones are built by
`ocplace.methods`; any object with this protocol can be scored). The harness owns scoring:
methods never see the ground truth (tuples, oracle, GT tokens), only what a robot would have: the
RGB-D image, the boxes from segmentation, the scene objects' table-frame AABBs of those boxes, the
instruction, the held object's footprint and the camera.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from ocplace.sim.dataset.records import SceneRecord

if TYPE_CHECKING:
    import jax


@dataclasses.dataclass(frozen=True)
class MethodOutput:
    """What one method did in one scene; the harness scores it."""

    mode: np.ndarray | None  # (2,) table-frame metres of the most probable placement; None: no placement
    samples: np.ndarray | None  # (num_samples, 2) table-frame metres; None: the method has no samples
    parsed: tuple[tuple[str, str], ...] | None = None  # (reference phrase, canonical relation) per tuple
    grounded: tuple[int, ...] | None = None  # visual-token index per parsed tuple (N = the table)
    failure: str | None = None  # why there is no placement (typed error message or flag), else None
    parse_note: str | None = None  # the LLM parser's fall-back reason or its disagreement with the offline parse
    # The least top grounding probability over the references (what the policy's refusal gate compares
    # with its threshold); None: the method does not ground references to tokens.
    confidence: float | None = None
    # Per parsed tuple, P over the visual tokens (N + 1 in box order, the table last): what the grounding knew
    # beyond its choice, recorded for the analysis of failures; None: the method does not report it.
    probabilities: tuple[tuple[float, ...], ...] | None = None
    decision: str | None = None  # how `grounded` was chosen from them ("argmax", "joint", "joint_fallback")


class Method(Protocol):
    """A trained method, ready to place."""

    @property
    def name(self) -> str:
        """The method's key in results (`ocplace evaluate --methods`)."""

    def describe(self) -> dict[str, Any]:
        """JSON-able: configs, seeds, checkpoint sha256, backbone fingerprint, parser and its cache."""

    def run(self, scenes: Sequence[SceneRecord], key: jax.Array) -> list[MethodOutput]:
        """One output per scene, in order. Must not read the records' tuples, oracle or token indices."""
