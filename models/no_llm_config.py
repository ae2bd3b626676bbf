"""Shapes of the no_llm model (`NoLlmConfig`), without JAX: a recipe holds one (docs/architecture.md)."""

from __future__ import annotations

import dataclasses


@dataclasses.dataclass(frozen=True)
class NoLlmConfig:
    """Shapes of the no_llm model; everything that shapes its parameters or its text."""

    dim: int = 512  # D, the backbone's embedding width
    reduction: int = 4  # adapter hidden width = D / reduction
    residual_ratio: float = 0.2
    hidden: int = 256  # relation MLP hidden width
    # The sentence is already a caption, so CLIP's "a photo of a {}." would only garble it.
    sentence_template: str = "{}"

    @property
    def adapters(self):
        """The `AdapterConfig` of the model's adapters."""
        from ocplace.models.adapters import AdapterConfig  # Flax behind it: this module stays light

        return AdapterConfig(self.dim, self.reduction, self.residual_ratio)

    def sentence_text(self, instruction: str) -> str:
        return self.sentence_template.format(" ".join(instruction.split()))
