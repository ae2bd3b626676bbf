"""The no_pretrain model's configuration (Ours' backbone from random weights), without JAX: a recipe holds one."""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, ClassVar

from ocplace.errors import TrainingError
from ocplace.models import offline_config

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


@dataclasses.dataclass(frozen=True)
class NoPretrainTrainConfig:
    TRAINS_TOWER: ClassVar[bool] = True  # the backbone's pretraining optimiser (`train/optim.make`)

    steps: int = 600  # 28,800 crops through the trunk: ~10 min on 2 cores at 128 px
    batch_size: int = 8  # scenes per step (each with all its visual tokens)
    learning_rate: float = 1e-3  # AdamW peak; linear warm-up, cosine decay to 2% (as the backbone pretraining)
    warmup_steps: int = 50
    weight_decay: float = 0.05  # matrices only
    augment: bool = True  # a random symmetry of the square per image
    seed: int = 0
    fraction: float = 1.0
    subset_seed: int = 0
    log_every: int = 50
    checkpoint_every: int = 200
    keep_checkpoints: int = 2

    def validate(self) -> None:
        if min(self.steps, self.batch_size, self.log_every, self.checkpoint_every) < 1:
            raise TrainingError("steps, batch_size, log_every and checkpoint_every must be positive")
        if not 0.0 < self.fraction <= 1.0:
            raise TrainingError(f"fraction must be in (0, 1], got {self.fraction}")


@dataclasses.dataclass(frozen=True)
class NoPretrainRecipe:
    model: NoPretrainConfig
    train: NoPretrainTrainConfig
