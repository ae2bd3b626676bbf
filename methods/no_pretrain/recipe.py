"""The no_pretrain model's configuration (Ours' backbone from random weights), without JAX: a recipe holds one."""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

from ocplace.errors import TrainingError
from ocplace.models import offline_config
from ocplace.train.schedule import Schedule

if TYPE_CHECKING:
    from ocplace.models.adapters import AdapterConfig


@dataclasses.dataclass(frozen=True)
class NoPretrainConfig:
    backbone: offline_config.OfflineConfig
    reduction: int = 4
    residual_ratio: float = 0.2
    max_logit_scale: float = 100.0  # CLIP's clamp on the learned temperature

    @property
    def adapters(self) -> AdapterConfig:
        """The `AdapterConfig` of the adapters trained with the tower."""
        from ocplace.models.adapters import AdapterConfig  # Flax behind it: this module stays light

        return AdapterConfig(self.backbone.embed_dim, self.reduction, self.residual_ratio)


def from_random(backbone: offline_config.OfflineConfig) -> offline_config.OfflineConfig:
    """`backbone`'s architecture with nothing pretrained."""
    return dataclasses.replace(backbone, trunk_init="random")


def default_config() -> NoPretrainConfig:
    """Ours' backbone (`offline_config.default_config`) from random weights."""
    return NoPretrainConfig(from_random(offline_config.default_config()))


def demo_config() -> NoPretrainConfig:
    return default_config()


def smoke_config() -> NoPretrainConfig:
    return NoPretrainConfig(from_random(offline_config.smoke_config()))


# ~10 min on 2 cores at 128 px: 28,800 crops through the trunk; AdamW as the backbone's pretraining (linear warm-up,
# cosine decay to 2% of the peak). A step is one batch of scenes, each with all its visual tokens.
SCHEDULE = Schedule(
    steps=600,
    batch_size=8,
    learning_rate=1e-3,
    warmup_steps=50,
    chunk_steps=1,
    checkpoint_every=200,
    weight_decay=0.05,
    optimiser="adamw_clipped",
)


@dataclasses.dataclass(frozen=True)
class NoPretrainRecipe:
    model: NoPretrainConfig
    schedule: Schedule = SCHEDULE
    augment: bool = True  # a random symmetry of the square per image
    log_every: int = 50
    subset_seed: int = 0

    def validate(self) -> None:
        problems = self.schedule.problems()
        if self.log_every < 1 or self.subset_seed < 0:
            problems.append(
                f"log_every must be positive, subset_seed at least 0, got {self.log_every}, {self.subset_seed}"
            )
        if problems:
            raise TrainingError("invalid training configuration: " + "; ".join(problems))


# The recipe at each experiment's scale (configs/<name>.py).
PRESETS = {
    "default": NoPretrainRecipe(default_config()),
    "demo": NoPretrainRecipe(
        demo_config(), dataclasses.replace(SCHEDULE, steps=75, warmup_steps=8, checkpoint_every=25), log_every=25
    ),
    "smoke": NoPretrainRecipe(
        smoke_config(),
        dataclasses.replace(SCHEDULE, steps=150, batch_size=4, warmup_steps=3, checkpoint_every=50),
        log_every=10,
    ),
}
