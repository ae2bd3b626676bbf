"""The no_pretrain model's configuration (Ours' backbone from random weights), without JAX: a recipe holds one."""

from __future__ import annotations

import dataclasses

from ocplace.models import offline_config


@dataclasses.dataclass(frozen=True)
class NoPretrainConfig:
    backbone: offline_config.OfflineConfig
    reduction: int = 4
    residual_ratio: float = 0.2
    max_logit_scale: float = 100.0  # CLIP's clamp on the learned temperature

    @property
    def adapters(self):
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
