"""The no_llm model's shapes (`NoLlmConfig`) and its training recipe (`NoLlmRecipe`), without JAX."""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

from ocplace.errors import TrainingError
from ocplace.models.adapter_settings import AdapterSettings
from ocplace.train.schedule import Schedule

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
class NoLlmRecipe:
    adapters: AdapterSettings = AdapterSettings()
    schedule: Schedule = Schedule(
        steps=10_000, batch_size=32, learning_rate=1e-3, warmup_steps=500, chunk_steps=1_000, checkpoint_every=5_000
    )
    relation_weight: float = 1.0  # loss = reference CE + relation_weight * relation CE
    hidden: int = 256  # relation MLP width
    subset_seed: int = 0  # nested subsets, as Ours'

    def validate(self) -> None:
        problems = self.schedule.problems() + self.adapters.problems()
        if self.hidden < 1 or self.subset_seed < 0:
            problems.append(
                f"hidden must be positive and subset_seed at least 0, got {self.hidden}, {self.subset_seed}"
            )
        if self.adapters.text_ratio is not None or self.adapters.normalise:
            problems.append("no_llm's adapters blend as the paper's: leave adapters.text_ratio none, normalise false")
        if problems:
            raise TrainingError("invalid training configuration: " + "; ".join(problems))

    def model_config(self, dim: int) -> NoLlmConfig:
        return NoLlmConfig(
            dim=dim, reduction=self.adapters.reduction, residual_ratio=self.adapters.residual_ratio, hidden=self.hidden
        )


# The recipe at each experiment's scale (configs/<name>.py).
PRESETS = {
    "default": NoLlmRecipe(),
    "demo": NoLlmRecipe(
        schedule=dataclasses.replace(
            NoLlmRecipe().schedule, steps=3_000, warmup_steps=200, chunk_steps=500, checkpoint_every=1_500
        )
    ),
    "smoke": NoLlmRecipe(
        schedule=Schedule(
            steps=120, batch_size=8, learning_rate=3e-3, warmup_steps=10, chunk_steps=40, checkpoint_every=40
        ),
        hidden=32,
    ),
}
