"""The offline backbone's architecture (`OfflineConfig`) and its named configurations, without JAX.

A recipe holds one, so an experiment is built and checked (`Experiment.validate`) before JAX is
imported: a bad `--set` fails in a fraction of a second. The network is `models/offline_backbone.py`.
"""

from __future__ import annotations

import dataclasses

from ocplace.errors import BackboneError
from ocplace.models import efficientnet_config
from ocplace.models.preprocessing import ImagePreprocessing
from ocplace.serial import bounded
from ocplace.vocabulary import CLIP_IMAGE_MEAN, CLIP_IMAGE_STD

VIT = "vit"
MINILM_DIM = 384
BICUBIC = 3  # PIL.Image.BICUBIC
VIT_DEPTH_FIELDS = ("layers", "heads", "mlp_dim")


@dataclasses.dataclass(frozen=True)
class OfflineConfig:
    """Architecture of the offline backbone (everything that shapes its parameters).

    `trunk` is "vit" (the fields `patch_size` ... `mlp_dim` shape it) or an EfficientNet-Lite
    variant ("lite0"), started from ImageNet weights (`trunk_init="imagenet"`) or at random, with
    its first `frozen_blocks` entries of `efficientnet_config.block_names` never trained.
    """

    trunk: str = "lite0"  # every recipe's; "vit" is kept for comparison (`vit_config`)
    trunk_init: str = "imagenet"  # "imagenet" (EfficientNet-Lite only) or "random"
    # The stem and first 12 blocks frozen, 160 px input: rule T of docs/settings.md on the dev splits and the
    # corpus' held-out categories (docs/offline_backbone.md, "Choosing the trunk").
    frozen_blocks: int = bounded(13, 0, 64)
    image_size: int = bounded(160, 16, 1024)
    patch_size: int = bounded(16, 1, 256)
    width: int = bounded(256, 1, 4096)  # the ViT's width; an EfficientNet-Lite trunk gives 1280 features
    layers: int = bounded(6, 1, 64)
    heads: int = bounded(4, 1, 64)
    mlp_dim: int = bounded(1024, 1, 16384)
    embed_dim: int = bounded(256, 1, 4096)  # D, the shared embedding width
    text_dim: int = bounded(MINILM_DIM, 1, 4096)  # width of the frozen text tower's sentence embedding
    text_max_length: int = bounded(32, 1, 512)  # MiniLM tokens per text; longer texts are truncated
    init_temperature: float = bounded(0.07, 1e-4, 10.0)  # CLIP's initial softmax temperature (logit scale 1 / 0.07)

    @property
    def is_vit(self) -> bool:
        return self.trunk == VIT

    @property
    def feature_width(self) -> int:
        """Width of the trunk's pooled features, the input of `visual_projection`."""
        return self.width if self.is_vit else efficientnet_config.HEAD_WIDTH

    @property
    def preprocessing(self):
        """The `ImagePreprocessing` of this trunk's crops."""
        mean, std = (
            (CLIP_IMAGE_MEAN, CLIP_IMAGE_STD)
            if self.is_vit
            else ((efficientnet_config.PIXEL_MEAN / 255,) * 3, (efficientnet_config.PIXEL_STD / 255,) * 3)
        )
        return ImagePreprocessing(
            resize=self.image_size, crop=(self.image_size, self.image_size), mean=mean, std=std, resample=BICUBIC
        )

    def problems(self) -> list[str]:
        try:
            self.validate()
        except BackboneError as error:
            return [str(error)]
        return []

    def validate(self) -> None:
        if not self.is_vit:
            efficientnet_config.config(self.trunk)
        if self.trunk_init not in ("imagenet", "random") or (self.is_vit and self.trunk_init == "imagenet"):
            raise BackboneError(
                f"trunk_init {self.trunk_init!r}: use 'random', or 'imagenet' with an EfficientNet-Lite trunk"
            )

    def vision_config(self):
        from transformers import CLIPVisionConfig

        return CLIPVisionConfig(
            image_size=self.image_size,
            patch_size=self.patch_size,
            hidden_size=self.width,
            intermediate_size=self.mlp_dim,
            num_hidden_layers=self.layers,
            num_attention_heads=self.heads,
            projection_dim=self.embed_dim,
        )

    def serial_omitted(self) -> tuple[str, ...]:
        """An EfficientNet trunk's text leaves out the ViT's depth, which does not shape it, so that its recipe
        key (and the cached backbones named by it) change only with what matters (`ocplace.serial`)."""
        return () if self.is_vit else VIT_DEPTH_FIELDS


def vit_config() -> OfflineConfig:
    """The first offline backbone: a 4.9M-parameter ViT trained from scratch (kept for comparison)."""
    return OfflineConfig(trunk=VIT, trunk_init="random", frozen_blocks=0)


def default_config() -> OfflineConfig:
    """EfficientNet-Lite0 from ImageNet, 128 px crops, stem and first 12 blocks frozen: the class defaults."""
    return OfflineConfig()


def smoke_config() -> OfflineConfig:
    """Ours' trunk at 32 px (cheap enough for tests), D = 32."""
    return dataclasses.replace(default_config(), image_size=32, embed_dim=32)
