"""CLIPort-Place (paper Table I): the attention stream of CLIPort, a pixel-wise placement affordance.

A fully convolutional U-Net over the top-down RGB-D image, downsampled to `width x height`
(default 160 x 120: 5.3 mm of table per pixel), with four channels: RGB normalised by CLIP's mean
and std, and the height above the table (camera height minus planar depth) in units of 10 cm.
Language enters as in CLIPort's decoder: the whole instruction's sentence embedding from the
backbone's text tower is projected per decoder stage and fused into the feature maps; we use
FiLM (x * (1 + gamma) + beta, tiled over pixels; CLIPort multiplies by the tiled projection, the
beta = 0 case), starting at the identity. The output is one logit per pixel; pixels whose centre
is not on the table get -inf, so the distribution lives on the placement area. Training: cross-
entropy against a pixel drawn from the oracle's feasible region; testing: the argmax pixel, mapped
back to the table plane through the camera. No rotation augmentation (it would swap left/right).

Pixels are `(u, v)`: u to the right, v down, centres at integers, of the downsampled image; a
flat index is `v * width + u`.
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import cast

import cv2
import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax

from ocplace import serial
from ocplace.methods.cliport.recipe import CliportConfig
from ocplace.models.baselines.trained_run import load_run
from ocplace.models.weights_file import unflatten_state
from ocplace.sim.camera import Camera
from ocplace.vocabulary import CLIP_IMAGE_MEAN, CLIP_IMAGE_STD

# ----------------------------------------------------------------------------- pixels and the table


def _scale(camera: Camera, config: CliportConfig) -> np.ndarray:
    """`(2,)` full-resolution pixels per downsampled pixel along u and v."""
    return np.array([camera.width / config.width, camera.height / config.height])


def pixel_to_table(pixels, camera: Camera, config: CliportConfig) -> np.ndarray:
    """`(..., 2)` downsampled pixels (u, v) -> `(..., 2)` points on the table plane z = 0."""
    full = (np.asarray(pixels, dtype=np.float64) + 0.5) * _scale(camera, config) - 0.5
    depth = np.full(full.shape[:-1], camera.position[2])  # planar depth of the table plane
    return camera.pixel_to_world(full, depth)[..., :2]


def table_to_pixel(points, camera: Camera, config: CliportConfig) -> np.ndarray:
    """`(..., 2)` table points -> `(..., 2)` downsampled pixel coordinates (u, v), not rounded."""
    full = camera.table_to_pixel(points)
    return (full + 0.5) / _scale(camera, config) - 0.5


def flat_to_pixel(index, config: CliportConfig) -> np.ndarray:
    index = np.asarray(index)
    return np.stack([index % config.width, index // config.width], axis=-1)


def pixel_to_flat(pixels, config: CliportConfig) -> np.ndarray:
    """`(..., 2)` pixel coordinates -> `(...,)` flat index of the pixel holding them (clipped to the image)."""
    rounded = np.rint(np.asarray(pixels)).astype(np.int64)
    u = np.clip(rounded[..., 0], 0, config.width - 1)
    v = np.clip(rounded[..., 1], 0, config.height - 1)
    return (v * config.width + u).astype(np.int32)


def table_mask(camera: Camera, config: CliportConfig) -> np.ndarray:
    """`(height, width)` bool: pixels whose centre lies on the table top."""
    u, v = np.meshgrid(np.arange(config.width), np.arange(config.height))
    points = pixel_to_table(np.stack([u, v], axis=-1), camera, config)
    bounds = config.table.bounds
    return np.all((points >= bounds[0]) & (points <= bounds[1]), axis=-1)


def prepare_image(
    rgb: np.ndarray, depth: np.ndarray, camera: Camera, config: CliportConfig
) -> tuple[np.ndarray, np.ndarray]:
    """`(rgb uint8 (h, w, 3), height float16 (h, w))` at the network's resolution (area-averaged)."""
    size = (config.width, config.height)
    small_rgb = cv2.resize(rgb, size, interpolation=cv2.INTER_AREA)
    small_depth = cv2.resize(np.asarray(depth, np.float32), size, interpolation=cv2.INTER_AREA)
    height = np.clip(camera.position[2] - small_depth, 0.0, config.max_height)
    return small_rgb, height.astype(np.float16)


# ----------------------------------------------------------------------------- the network


class FiLM(nn.Module):
    """x * (1 + gamma(text)) + beta(text), per channel, tiled over pixels; the identity at initialisation."""

    @nn.compact
    def __call__(self, x, text):
        channels = x.shape[-1]
        gamma_beta = nn.Dense(2 * channels, kernel_init=nn.initializers.zeros)(text)
        gamma, beta = jnp.split(gamma_beta[..., None, None, :], 2, axis=-1)
        return x * (1.0 + gamma) + beta


class AttentionNet(nn.Module):
    """`(B, h, w, 4)` float RGB-D and `(B, D)` sentence embeddings -> `(B, h, w)` logits."""

    config: CliportConfig

    @nn.compact
    def __call__(self, image, text):
        x, skips = image, []
        for level, channels in enumerate(self.config.channels):
            stride = 1 if level == 0 else 2
            x = nn.relu(nn.Conv(channels, (3, 3), strides=stride, name=f"down{level}_a")(x))
            x = nn.relu(nn.Conv(channels, (3, 3), name=f"down{level}_b")(x))
            skips.append(x)
        x = FiLM(name="film_bottleneck")(x, text)
        for level in reversed(range(len(self.config.channels) - 1)):
            skip = skips[level]
            x = jax.image.resize(x, (*x.shape[:1], *skip.shape[1:3], x.shape[-1]), "nearest")
            x = jnp.concatenate([x, skip], axis=-1)
            x = nn.relu(nn.Conv(self.config.channels[level], (3, 3), name=f"up{level}")(x))
            x = FiLM(name=f"film{level}")(x, text)
        return nn.Conv(1, (1, 1), name="logits")(x)[..., 0]


def network_input(rgb, height, config: CliportConfig):
    """uint8 `(B, h, w, 3)` and `(B, h, w)` metres -> float32 `(B, h, w, 4)`."""
    scaled = rgb.astype(jnp.float32) / 255.0
    normalised = (scaled - jnp.asarray(CLIP_IMAGE_MEAN)) / jnp.asarray(CLIP_IMAGE_STD)
    return jnp.concatenate([normalised, (height.astype(jnp.float32) / config.height_unit)[..., None]], axis=-1)


def pixel_logits(config: CliportConfig, params, rgb, height, text, mask):
    """`(B, h * w)` flat logits, -inf off the table (`mask (h, w)` or `(B, h, w)` bool)."""
    logits = cast(jax.Array, AttentionNet(config).apply({"params": params}, network_input(rgb, height, config), text))
    return jnp.where(mask.reshape(*mask.shape[:-2], -1), logits.reshape(logits.shape[0], -1), -jnp.inf)


def pixel_loss(config: CliportConfig, params, rgb, height, text, mask, targets):
    """Mean cross-entropy against `targets (B,)` flat pixel indices (which must be on the table)."""
    logits = pixel_logits(config, params, rgb, height, text, mask)
    return jnp.mean(optax.softmax_cross_entropy_with_integer_labels(logits, targets))


def init_network(config: CliportConfig, dim: int, key) -> dict:
    image = jnp.zeros((1, config.height, config.width, 4))
    return jax.jit(AttentionNet(config).init)(key, image, jnp.zeros((1, dim)))["params"]


def _distribution(config: CliportConfig, params, rgb, height, text, mask):
    return jax.nn.softmax(pixel_logits(config, params, rgb, height, text, mask), axis=-1)


jit_distribution = jax.jit(_distribution, static_argnums=0)


def _inverse_cdf(cdf: jax.Array, targets: jax.Array) -> jax.Array:
    """The first index whose cumulative mass exceeds each target (never one past the last entry with mass)."""
    index = jnp.searchsorted(cdf, targets, side="right")
    has_mass = jnp.diff(cdf, prepend=0.0) > 0.0
    last = cdf.shape[-1] - 1 - jnp.argmax(has_mass[::-1])  # u * total may round up to total
    return jnp.minimum(index, last)


@functools.partial(jax.jit, static_argnames=("num_samples", "width"))
def sample_pixels(key, probabilities: jax.Array, num_samples: int, width: int) -> jax.Array:
    """`(num_samples,)` flat pixel indices drawn from one `(h * w,)` distribution by inverse CDF: a row by the
    rows' masses, then a pixel of it. Two short float32 cumulative sums (h, then w entries) keep every
    pixel's share to float rounding; one over all h * w pixels would not. It replaces Gumbel-max
    (`jax.random.categorical`: h * w draws per sample), the same distribution (tests/test_baselines.py)."""
    row_key, pixel_key = jax.random.split(key)
    rows = probabilities.reshape(-1, width)
    row_cdf = jnp.cumsum(rows.sum(axis=1))
    row = _inverse_cdf(row_cdf, jax.random.uniform(row_key, (num_samples,)) * row_cdf[-1])
    cdf = jnp.cumsum(rows[row], axis=1)  # (num_samples, width)
    targets = jax.random.uniform(pixel_key, (num_samples,)) * cdf[:, -1]
    return row * width + jax.vmap(_inverse_cdf)(cdf, targets)


def mode_and_samples(
    key, probabilities: np.ndarray, num_samples: int, camera: Camera, config: CliportConfig
) -> tuple[np.ndarray, np.ndarray]:
    """`(mode (2,), samples (num_samples, 2))` table points from one scene's `(h * w,)` pixel distribution.

    The mode is the argmax pixel's centre; a sample is a pixel drawn from the distribution
    (`sample_pixels`) plus a uniform offset inside it, clipped to the table.
    """
    pick_key, jitter_key = jax.random.split(key)
    flat = np.asarray(sample_pixels(pick_key, jnp.asarray(probabilities), num_samples, config.width))
    jitter = np.asarray(jax.random.uniform(jitter_key, (num_samples, 2), minval=-0.5, maxval=0.5))
    mode = pixel_to_table(flat_to_pixel(int(np.argmax(probabilities)), config), camera, config)
    samples = pixel_to_table(flat_to_pixel(flat, config) + jitter, camera, config)
    samples = np.clip(samples, config.table.bounds[0], config.table.bounds[1])  # edge pixels overhang the table
    return mode.astype(np.float32), samples.astype(np.float32)


def load_params(run_dir: Path) -> tuple[dict, dict, str]:
    """`(params, run_meta, weights sha256)` of a finished run."""
    run_meta, arrays, sha = load_run(run_dir, "cliport")
    config = serial.from_dict(CliportConfig, run_meta["network"])
    template = jax.eval_shape(lambda: init_network(config, run_meta["dim"], jax.random.key(0)))
    return unflatten_state(arrays, template), run_meta, sha
