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
