"""EfficientNet-Lite (Tan & Le 2019, the Lite variants of TF's `efficientnet/lite`) in Flax linen, NHWC.

Lite differs from EfficientNet-B*: ReLU6 instead of swish, no squeeze-excite, and a stem (32) and
head (1280) whose widths do not scale with the width multiplier; the first and last stages do not
scale with the depth multiplier either. Convolutions pad like TF's "SAME" (the extra row and column
go after), so ImageNet weights converted from TF (and the PyTorch port) give the same logits.

Variables are the usual Flax two collections (the model always runs in inference mode):
    params        trainable: conv kernels `(k, k, in, out)`, depthwise kernels `(k, k, C)`,
                  batch-norm `scale` and `bias`, the classifier `kernel (1280, 1000)` and `bias`
    batch_stats   batch-norm running `mean` and `var`, never updated here (fine-tuning keeps the
                  ImageNet statistics: the trunk is used frozen or nearly so)
Top-level names run in forward order: `stem`, `blocks_00` ... `blocks_NN`, `head`, `classifier`
(`block_names(variant)`), so an optax mask can freeze a prefix (`trainable_mask`).

Input: uint8 pixels `(B, H, W, 3)` in RGB, normalised as the TF Lite models were trained,
`(x - 127) / 128` (the PyTorch port's README shows ImageNet mean/std, but its weights are converted
from TF, and the TF Lite builder uses mean 127, std 128).
"""

from __future__ import annotations

import functools
import math
from typing import Any, cast

import flax.linen as nn
import jax
import jax.numpy as jnp

from ocplace.models.efficientnet_config import (
    HEAD_WIDTH,
    NUM_CLASSES,
    PIXEL_MEAN,
    PIXEL_STD,
    STEM_WIDTH,
    BlockConfig,
    LiteConfig,
    config,
)

BN_EPSILON = 1e-3


def trainable_mask(params: dict, frozen: int) -> dict:
    """A pytree of bools over `params` (the `params` collection): False for the first `frozen`
    top-level entries of `block_names` order, True after. For `optax.masked` / `multi_transform`."""
    frozen_names = set(_ordered(params)[:frozen])
    return {
        name: jax.tree_util.tree_map(lambda _, trainable=name not in frozen_names: trainable, subtree)
        for name, subtree in params.items()
    }


def _ordered(params: dict) -> list[str]:
    """The top-level names of `params` in forward order (`blocks_NN` sort by their zero-padded index)."""
    rank = {"stem": 0, "head": 2, "classifier": 3}
    return sorted(params, key=lambda name: (rank.get(name, 1), name))


# ----------------------------------------------------------------------------- layers


def same_pads(size: int, kernel: int, stride: int) -> tuple[int, int]:
    """TF "SAME" padding of one axis: output `ceil(size / stride)`, the odd pixel padded after."""
    out = -(-size // stride)
    total = max((out - 1) * stride + kernel - size, 0)
    return total // 2, total - total // 2


def depthwise_conv(x: jax.Array, kernel: jax.Array, stride: int) -> jax.Array:
    """Depthwise "SAME" convolution of `x (B, H, W, C)` with `kernel (k, k, C)`.

    A sum of k*k shifted, strided slices times per-channel weights: XLA:CPU runs
    `conv_general_dilated` with `feature_group_count=C` about 6x slower than this.
    """
    k = kernel.shape[0]
    (top, bottom), (left, right) = same_pads(x.shape[1], k, stride), same_pads(x.shape[2], k, stride)
    padded = jnp.pad(x, ((0, 0), (top, bottom), (left, right), (0, 0)))
    out_h, out_w = -(-x.shape[1] // stride), -(-x.shape[2] // stride)
    total = None
    for i in range(k):
        for j in range(k):
            window = padded[:, i : i + stride * (out_h - 1) + 1 : stride, j : j + stride * (out_w - 1) + 1 : stride, :]
            term = window * kernel[i, j]
            total = term if total is None else total + term
    assert total is not None, "a kernel has at least one tap"
    return total


class DepthwiseConv(nn.Module):
    """Depthwise convolution without bias; parameter `kernel (k, k, C)`."""

    kernel_size: int
    stride: int

    @nn.compact
    def __call__(self, x):
        kernel = self.param(
            "kernel",
            nn.initializers.lecun_normal(in_axis=(0, 1), out_axis=2),
            (self.kernel_size, self.kernel_size, x.shape[-1]),
        )
        return depthwise_conv(x, kernel, self.stride)


def _conv(features: int, kernel: int = 1, stride: int = 1, name: str | None = None) -> nn.Conv:
    return nn.Conv(features, (kernel, kernel), (stride, stride), padding="SAME", use_bias=False, name=name)


def _bn(name: str, calibrate: bool = False) -> nn.BatchNorm:
    """Inference-mode batch norm; `calibrate`: normalise by the batch's own statistics and store
    exactly them as the running ones (momentum 0)."""
    return nn.BatchNorm(use_running_average=not calibrate, momentum=0.0, epsilon=BN_EPSILON, name=name)


class MBConv(nn.Module):
    """Inverted residual: 1x1 expand, depthwise k x k, 1x1 project (linear), identity skip."""

    block: BlockConfig
    calibrate: bool = False

    @nn.compact
    def __call__(self, x):
        b, calibrate = self.block, self.calibrate
        y = x
        if b.expand != 1:
            y = nn.relu6(_bn("expand_bn", calibrate)(_conv(b.hidden, name="expand_conv")(y)))
        y = nn.relu6(_bn("depthwise_bn", calibrate)(DepthwiseConv(b.kernel, b.stride, name="depthwise_conv")(y)))
        y = _bn("project_bn", calibrate)(_conv(b.out, name="project_conv")(y))
        return x + y if b.residual else y


class ConvBN(nn.Module):
    """Convolution, batch norm, ReLU6 (the stem and the head)."""

    features: int
    kernel: int
    stride: int
    calibrate: bool = False

    @nn.compact
    def __call__(self, x):
        return nn.relu6(_bn("bn", self.calibrate)(_conv(self.features, self.kernel, self.stride, name="conv")(x)))


class EfficientNetLite(nn.Module):
    """Pixels `(B, H, W, 3)` uint8 -> pooled features `(B, 1280)`, or logits `(B, 1000)`."""

    config: LiteConfig
    calibrate: bool = False  # see `calibrate_batch_stats`

    @nn.compact
    def __call__(self, pixels, classify: bool = True):
        x = normalise(pixels)
        x = ConvBN(STEM_WIDTH, 3, 2, self.calibrate, name="stem")(x)
        for index, block in enumerate(self.config.blocks):
            x = MBConv(block, self.calibrate, name=f"blocks_{index:02d}")(x)
        x = ConvBN(HEAD_WIDTH, 1, 1, self.calibrate, name="head")(x)
        pooled = x.mean(axis=(1, 2))
        # The classifier is always created, so one variables tree serves `features` and `logits`.
        logits = nn.Dense(NUM_CLASSES, name="classifier")(pooled)
        return logits if classify else pooled


def normalise(pixels: jax.Array) -> jax.Array:
    """uint8 (or 0..255 float) pixels `(B, H, W, 3)` -> float32 `(x - 127) / 128`."""
    return (jnp.asarray(pixels, jnp.float32) - PIXEL_MEAN) / PIXEL_STD


# ----------------------------------------------------------------------------- pure functions


@functools.cache
def module(variant: str = "lite0") -> EfficientNetLite:
    return EfficientNetLite(config(variant))


@functools.partial(jax.jit, static_argnames=("variant",))
def features(params: dict, pixels: jax.Array, variant: str = "lite0") -> jax.Array:
    """Globally average-pooled head features `(B, 1280)` of pixels `(B, H, W, 3)`.

    `params` is the variables dict `{"params": ..., "batch_stats": ...}` (`load_pretrained`).
    """
    return cast(jax.Array, module(variant).apply(params, pixels, classify=False))  # no `mutable`: the output alone


@functools.partial(jax.jit, static_argnames=("variant",))
def logits(params: dict, pixels: jax.Array, variant: str = "lite0") -> jax.Array:
    """ImageNet-1k logits `(B, 1000)` of pixels `(B, H, W, 3)`."""
    return cast(jax.Array, module(variant).apply(params, pixels, classify=True))  # no `mutable`: the output alone


@functools.partial(jax.jit, static_argnames=("variant",))
def calibrate_batch_stats(variables: dict, pixels, variant: str = "lite0") -> dict:
    """`variables` with every batch-norm statistic set to the mean and variance its layer sees on
    `pixels (B, H, W, 3)`, layer after layer (each normalised by its own new statistics).

    A randomly initialised trunk with mean-0 / variance-1 statistics blows its activations up
    block after block until every ReLU6 saturates and the pooled features are constant; this
    data-dependent initialisation keeps them normalised, as training-mode batch norm would. Jitted
    (issue 42): XLA's fusion rounds the statistics otherwise than op by op, within 1e-5 (every variance
    relative, every mean in units of its channel's standard deviation: tests/test_efficientnet.py), at
    a fifth of the time and less memory (docs/performance.md).
    """
    _, updated = EfficientNetLite(config(variant), calibrate=True).apply(
        variables, pixels, classify=False, mutable=["batch_stats"]
    )
    return {**variables, "batch_stats": updated["batch_stats"]}


def variable_shapes(variant: str = "lite0", image_size: int | None = None) -> dict:
    """The variables tree as `jax.ShapeDtypeStruct` leaves (nothing is computed)."""
    size = image_size or config(variant).resolution
    pixels = jax.ShapeDtypeStruct((1, size, size, 3), jnp.uint8)
    return jax.eval_shape(module(variant).init, jax.random.key(0), pixels)


@functools.partial(jax.jit, static_argnames=("variant",))
def init(key: jax.Array, variant: str = "lite0") -> dict[str, Any]:
    """Randomly initialised variables (ImageNet weights: `imagenet_weights.load_pretrained`); jitted,
    the same bits as op by op."""
    return dict(module(variant).init(key, jnp.zeros((1, 32, 32, 3), jnp.uint8)))


def count_params(tree: dict) -> int:
    return sum(math.prod(leaf.shape) for leaf in jax.tree_util.tree_leaves(tree))
