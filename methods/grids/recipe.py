"""Raw Image Grids' configuration (`GridConfig`), without JAX: a recipe holds one."""

from __future__ import annotations

import dataclasses

import numpy as np

from ocplace.errors import TrainingError
from ocplace.sim.workspace import DEFAULT_TABLE, Table
from ocplace.train.schedule import Schedule


@dataclasses.dataclass(frozen=True)
class GridConfig:
    columns: int = 8  # cells along x (10 cm each on the 0.8 m table)
    rows: int = 6  # cells along y (10 cm each on the 0.6 m table)
    table: Table = DEFAULT_TABLE
    crop_size: int = 224  # cell images are resized to this, like object crops
    num_frequencies: int = 4  # NeRF bands: sin/cos(2^k pi p), k < num_frequencies
    position_hidden: int = 64  # width of the positional MLP's hidden layer
    reduction: int = 4  # adapter hidden width = D / reduction (as ours)
    residual_ratio: float = 0.2  # adapter blend (as ours)

    @property
    def num_cells(self) -> int:
        return self.columns * self.rows

    @property
    def cell_size(self) -> np.ndarray:
        """`(2,)` metres."""
        cell_size: np.ndarray = 2.0 * np.asarray(self.table.half_extents) / np.array([self.columns, self.rows])
        return cell_size


def smoke_grid_config() -> GridConfig:
    """A coarse 4 x 3 grid with small crops, for tests."""
    return GridConfig(columns=4, rows=3, crop_size=32, num_frequencies=2, position_hidden=16)


@dataclasses.dataclass(frozen=True)
class GridsRecipe:
    grid: GridConfig
    schedule: Schedule

    def validate(self) -> None:
        if problems := self.schedule.problems():
            raise TrainingError("invalid training configuration: " + "; ".join(problems))


# The recipe at each experiment's scale (configs/<name>.py). The default is the paper's budget for the adapters:
# 200K steps at batch 1, warm-up then cosine decay.
PRESETS = {
    "default": GridsRecipe(
        GridConfig(),
        Schedule(
            steps=200_000,
            batch_size=1,
            learning_rate=1e-4,
            warmup_steps=1_000,
            chunk_steps=2_000,
            checkpoint_every=50_000,
        ),
    ),
    "demo": GridsRecipe(
        GridConfig(),
        Schedule(
            steps=4_000, batch_size=4, learning_rate=1e-3, warmup_steps=100, chunk_steps=1_000, checkpoint_every=2_000
        ),
    ),
    "smoke": GridsRecipe(
        smoke_grid_config(),
        Schedule(steps=120, batch_size=4, learning_rate=1e-2, warmup_steps=5, chunk_steps=40, checkpoint_every=40),
    ),
}
