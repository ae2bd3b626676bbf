"""Raw Image Grids (paper Table I): grid cells of the workspace image instead of object crops.

The placement area (the table top, 0.8 x 0.6 m) is cut into `columns x rows` cells (default
8 x 6: 10 cm squares, about 76 x 76 px in a 640 x 480 render). Each cell's image is encoded by the
backbone's image tower; a NeRF-style sin/cos embedding of the cell centre, through a small MLP,
is added to it; the same CLIP-Adapters as ours adapt the cell tokens and the text tokens. One text
token per parsed tuple, "<relation phrase> the <reference>" (e.g. "to the left of the red bowl"):
relations enter as words, which is all a grid of cells can use. The chosen cell maximises the sum
(we take the mean, same argmax) of cosine similarities with all text tokens; the placement is drawn
uniformly among the 5 mm metric-grid points inside that cell where the held object fits on the
table and clears every scene box (the cell's points themselves when none fits).

Cells are indexed `ix * rows + iy` (ix left to right, iy front to back), like `sim.metric.Grid`.
"""

from __future__ import annotations

import functools
from pathlib import Path

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax

from ocplace import serial
from ocplace.methods.grids.recipe import GridConfig
from ocplace.models.adapters import ClipAdapter, blend
from ocplace.models.backbone import PromptConfig
from ocplace.models.baselines.trained_run import load_run
from ocplace.models.grounding import l2_normalize
from ocplace.models.weights_file import unflatten_state
from ocplace.sim import language, metric, relations
from ocplace.sim.boxes import square_crop
from ocplace.sim.camera import Camera

# Tuple texts are whole phrases, not object names: no "a photo of a {}." prompt.
PLAIN_PROMPT = PromptConfig(template="{}", table_phrases=(), table_text="")


# ----------------------------------------------------------------------------- cell geometry


def cell_of(points, config: GridConfig) -> np.ndarray:
    """`(...,)` int32 flat cell index of table-frame points `(..., 2)`; points off the table are clipped in."""
    points = np.asarray(points, dtype=np.float64)
    low = config.table.bounds[0]
    counts = np.array([config.columns, config.rows])
    index = np.clip(np.floor((points - low) / config.cell_size), 0, counts - 1).astype(np.int32)
    return index[..., 0] * config.rows + index[..., 1]


def cell_bounds(cells, config: GridConfig) -> np.ndarray:
    """`(..., 2, 2)` `[[xmin, ymin], [xmax, ymax]]` of flat cell indices `(...,)`."""
    cells = np.asarray(cells)
    index = np.stack([cells // config.rows, cells % config.rows], axis=-1)
    low = config.table.bounds[0] + index * config.cell_size
    return np.stack([low, low + config.cell_size], axis=-2)


def cell_centres(config: GridConfig) -> np.ndarray:
    """`(num_cells, 2)` centres in flat-index order."""
    bounds = cell_bounds(np.arange(config.num_cells), config)
    return bounds.mean(axis=-2)


def cell_pixel_boxes(camera: Camera, config: GridConfig) -> np.ndarray:
    """`(num_cells, 4)` float pixel boxes `(u0, v0, u1, v1)` of the cells (image v grows towards -y)."""
    bounds = cell_bounds(np.arange(config.num_cells), config)
    top_left = camera.table_to_pixel(np.stack([bounds[:, 0, 0], bounds[:, 1, 1]], axis=-1))
    bottom_right = camera.table_to_pixel(np.stack([bounds[:, 1, 0], bounds[:, 0, 1]], axis=-1))
    return np.concatenate([top_left, bottom_right], axis=-1)


def cell_crops(rgb: np.ndarray, camera: Camera, config: GridConfig) -> np.ndarray:
    """uint8 `(num_cells, S, S, 3)`: each cell's pixels (no margin), resized to `config.crop_size`."""
    return np.stack(
        [square_crop(rgb, box, padding=0.0, size=config.crop_size) for box in cell_pixel_boxes(camera, config)]
    )


# ----------------------------------------------------------------------------- text tokens


def tuple_text(reference: str, relation: str) -> str:
    """The text token of one tuple: the seen relation phrase and the reference, e.g. "behind the red bowl".

    "middle" has no object phrase; with an object (a parse the metric cannot satisfy) its table
    phrase is used, so every parse gets a text.
    """
    is_table = reference.strip().lower() in ("table", "the table")
    phrase_kind = is_table or not relations.relation(relation).applies_to_objects
    return f"{language.seen_phrase(relation, phrase_kind)} the {language.TABLE_NAME if is_table else reference}"


# ----------------------------------------------------------------------------- the model


def positional_encoding(points, config: GridConfig):
    """NeRF's gamma(p): `(..., 2)` table points -> `(..., 2 + 4F)` [p, sin(2^k pi p), cos(2^k pi p)].

    Points are scaled by the table's half-extents to [-1, 1] first, so the lowest band spans the table.
    """
    scaled = jnp.asarray(points, jnp.float32) / jnp.asarray(config.table.half_extents, jnp.float32)
    bands = (2.0 ** jnp.arange(config.num_frequencies, dtype=jnp.float32)) * jnp.pi
    angles = (scaled[..., None, :] * bands[:, None]).reshape(*scaled.shape[:-1], -1)
    return jnp.concatenate([scaled, jnp.sin(angles), jnp.cos(angles)], axis=-1)


class GridsModel(nn.Module):
    """Cell and text tokens -> `(..., num_cells)` logits."""

    config: GridConfig
    dim: int

    @nn.compact
    def __call__(self, cells, text, text_mask, logit_scale):
        """cells `(..., C, D)`, text `(..., L, D)`, text_mask `(..., L)` bool -> logits `(..., C)`."""
        cfg = self.config
        gamma = positional_encoding(cell_centres(cfg), cfg)
        hidden = nn.relu(nn.Dense(cfg.position_hidden, name="position_in")(gamma))
        # Zero-initialised: training starts from the plain backbone features and learns the offsets.
        visual = cells + nn.Dense(self.dim, kernel_init=nn.initializers.zeros, name="position_out")(hidden)
        visual = blend(visual, ClipAdapter(self.dim, cfg.reduction, name="visual")(visual), cfg.residual_ratio)
        text = blend(text, ClipAdapter(self.dim, cfg.reduction, name="text")(text), cfg.residual_ratio)
        sims = jnp.einsum("...ld,...cd->...lc", l2_normalize(text), l2_normalize(visual))
        mean = jnp.sum(jnp.where(text_mask[..., None], sims, 0.0), axis=-2) / jnp.maximum(
            jnp.sum(text_mask, axis=-1, keepdims=True), 1
        )
        return logit_scale * mean


@functools.partial(jax.jit, static_argnums=(0, 1))
def init_grids(config: GridConfig, dim: int, key) -> dict:
    cells = jnp.zeros((config.num_cells, dim))
    text = jnp.zeros((1, dim))
    return GridsModel(config, dim).init(key, cells, text, jnp.ones((1,), bool), 1.0)["params"]


def grid_logits(config: GridConfig, params, cells, text, text_mask, logit_scale):
    return GridsModel(config, cells.shape[-1]).apply({"params": params}, cells, text, text_mask, logit_scale)


def grid_loss(config: GridConfig, params, cells, text, text_mask, targets, logit_scale):
    """Mean cross-entropy over a batch: cells `(B, C, D)`, text `(B, L, D)`, targets `(B,)` cell indices."""
    logits = grid_logits(config, params, cells, text, text_mask, logit_scale)
    return jnp.mean(optax.softmax_cross_entropy_with_integer_labels(logits, targets))


jit_grid_logits = jax.jit(grid_logits, static_argnums=0)


# ----------------------------------------------------------------------------- placement inside a cell


def sample_in_cell(
    key, free: np.ndarray, cell: int, num_samples: int, config: GridConfig, grid: metric.Grid = metric.DEFAULT_GRID
) -> tuple[np.ndarray, np.ndarray, bool]:
    """`(samples (num_samples, 2), mode (2,), collision_free)` uniform over the metric-grid points in `cell`.

    `free (nx, ny)` marks the points where the held object fits (`common.free_grid`). Only free
    points are drawn when the cell has any; the mode is the free point nearest the cell's centre.
    Without a free point, every point of the cell is used and `collision_free` is False.
    """
    (x0, y0), (x1, y1) = cell_bounds(cell, config)
    centres = grid.cell_centres()
    inside = (centres[..., 0] >= x0) & (centres[..., 0] < x1) & (centres[..., 1] >= y0) & (centres[..., 1] < y1)
    candidates = centres[inside & free]
    collision_free = len(candidates) > 0
    if not collision_free:
        candidates = centres[inside]
    mode = candidates[np.argmin(np.sum((candidates - [(x0 + x1) / 2, (y0 + y1) / 2]) ** 2, axis=-1))]
    picks = np.asarray(jax.random.randint(key, (num_samples,), 0, len(candidates)))
    return candidates[picks].astype(np.float32), mode.astype(np.float32), collision_free


def load_params(run_dir: Path) -> tuple[dict, dict, str]:
    """`(params, run_meta, weights sha256)` of a finished run."""
    run_meta, arrays, sha = load_run(run_dir, "grids")
    config = serial.from_dict(GridConfig, run_meta["grid"])
    dim = int(arrays["['visual']['up']['kernel']"].shape[-1])  # the feature size is not in the run's config
    template = jax.eval_shape(lambda: init_grids(config, dim, jax.random.key(0)))
    return unflatten_state(arrays, template), run_meta, sha
