"""Shapes of the no_llm model (`NoLlmConfig`), without JAX: a recipe holds one (docs/architecture.md)."""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

from ocplace.errors import TrainingError

if TYPE_CHECKING:
    from ocplace.models.adapters import AdapterConfig


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
    def adapters(self) -> AdapterConfig:
        """The `AdapterConfig` of the model's adapters."""
        from ocplace.models.adapters import AdapterConfig  # Flax behind it: this module stays light

        return AdapterConfig(self.dim, self.reduction, self.residual_ratio)

    def sentence_text(self, instruction: str) -> str:
        return self.sentence_template.format(" ".join(instruction.split()))


@dataclasses.dataclass(frozen=True)
class NoLlmTrainConfig:
    steps: int = 10_000
    batch_size: int = 32
    learning_rate: float = 1e-3  # Adam peak, linear warm-up then cosine decay to 0
    warmup_steps: int = 500
    relation_weight: float = 1.0  # loss = reference CE + relation_weight * relation CE
    hidden: int = 256  # relation MLP width
    reduction: int = 4
    residual_ratio: float = 0.2
    seed: int = 0  # initial weights and example order
    fraction: float = 1.0
    subset_seed: int = 0  # nested subsets, as train.ours
    chunk_steps: int = 1_000
    checkpoint_every: int = 5_000
    keep_checkpoints: int = 2

    def validate(self) -> None:
        if self.steps < 1 or self.batch_size < 1 or self.chunk_steps < 1:
            raise TrainingError("steps, batch_size and chunk_steps must be positive")
        if not 0.0 < self.fraction <= 1.0:
            raise TrainingError(f"fraction must be in (0, 1], got {self.fraction}")
        if self.checkpoint_every % self.chunk_steps:
            raise TrainingError("checkpoint_every must be a multiple of chunk_steps")

    def model_config(self, dim: int) -> NoLlmConfig:
        return NoLlmConfig(dim=dim, reduction=self.reduction, residual_ratio=self.residual_ratio, hidden=self.hidden)
