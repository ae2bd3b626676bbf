"""CLIPort-Place's configuration (`CliportConfig`), without JAX: a recipe holds one."""

from __future__ import annotations

import dataclasses

from ocplace.errors import TrainingError
from ocplace.sim.workspace import DEFAULT_TABLE, Table
from ocplace.train.schedule import Schedule


@dataclasses.dataclass(frozen=True)
class CliportConfig:
    width: int = 160  # input and output resolution (pixels)
    height: int = 120
    channels: tuple[int, ...] = (16, 32, 64, 64)  # U-Net widths, full resolution first; each next halves it
    height_unit: float = 0.10  # metres per unit of the height channel
    max_height: float = 0.40  # heights are clipped to [0, max_height]
    table: Table = DEFAULT_TABLE

    @property
    def num_pixels(self) -> int:
        return self.width * self.height


def smoke_config() -> CliportConfig:
    """40 x 30 pixels, two narrow levels: compiles and trains in seconds."""
    return CliportConfig(width=40, height=30, channels=(8, 16))


@dataclasses.dataclass(frozen=True)
class CliportRecipe:
    network: CliportConfig
    schedule: Schedule
    num_targets: int = 16  # feasible pixels cached per scene

    def validate(self) -> None:
        problems = self.schedule.problems()
        if self.num_targets < 1:
            problems.append(f"num_targets must be at least 1, got {self.num_targets}")
        if problems:
            raise TrainingError("invalid training configuration: " + "; ".join(problems))


# The recipe at each experiment's scale (configs/<name>.py). The default: 0.6-1.3 s per step of 8 on 2 CPU cores,
# 10-20 min, 4 epochs of 2000 scenes (docs/baselines.md).
PRESETS = {
    "default": CliportRecipe(
        CliportConfig(),
        Schedule(steps=1_000, batch_size=8, learning_rate=1e-3, warmup_steps=50, chunk_steps=50, checkpoint_every=250),
    ),
    "demo": CliportRecipe(
        CliportConfig(),
        Schedule(steps=100, batch_size=8, learning_rate=1e-3, warmup_steps=10, chunk_steps=50, checkpoint_every=50),
    ),
    "smoke": CliportRecipe(
        smoke_config(),
        Schedule(steps=60, batch_size=4, learning_rate=3e-3, warmup_steps=5, chunk_steps=20, checkpoint_every=20),
        num_targets=4,
    ),
}
