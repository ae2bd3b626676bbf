"""A training budget without JAX (`Schedule`), so the recipes that hold one (each row's `recipe.py`) build and
check before JAX is imported and a bad `--set` fails at once."""

from __future__ import annotations

import dataclasses
import typing
from dataclasses import MISSING
from typing import Any, Literal, TypeVar

from ocplace.errors import TrainingError
from ocplace.serial import bounded

OPTIMISERS = ("adam", "adamw_clipped")
R = TypeVar("R")


@dataclasses.dataclass(frozen=True)
class Schedule:
    """Optimisation budget of a recipe (`train/optim.make`): `adam` (the adapters', decoupled decay on every leaf
    when `weight_decay` is set), or `adamw_clipped` (an image tower's: gradient norm clipped to 1, decay on
    matrices only); both warm up linearly, then decay by a cosine (to 0, a tower's to a share of the peak)."""

    steps: int = bounded(MISSING, 1, 10_000_000, help="optimisation steps")
    batch_size: int = bounded(MISSING, 1, 65_536, help="scenes per step")
    learning_rate: float = bounded(MISSING, 0.0, 10.0, help="peak learning rate, after the warm-up")
    warmup_steps: int = bounded(MISSING, 0, 10_000_000, help="steps of the linear warm-up to the peak")
    chunk_steps: int = bounded(MISSING, 1, 100_000, help="steps fused into one jitted lax.scan call")
    checkpoint_every: int = bounded(MISSING, 1, 10_000_000, help="steps between checkpoints; a multiple of chunk_steps")
    keep_checkpoints: int = bounded(2, 1, 1000, help="newest checkpoints kept to resume from")
    weight_decay: float = bounded(0.0, 0.0, 10.0, help="decoupled weight decay (0: none)")
    optimiser: Literal["adam", "adamw_clipped"] = "adam"

    def problems(self) -> list[str]:
        """What is wrong with this budget (`validate` raises with it)."""
        problems = []
        if min(self.steps, self.batch_size, self.chunk_steps, self.keep_checkpoints) < 1:
            problems.append("steps, batch_size, chunk_steps and keep_checkpoints must be positive")
        elif self.checkpoint_every < 1 or self.checkpoint_every % self.chunk_steps:
            problems.append(
                f"checkpoint_every ({self.checkpoint_every}) must be a positive multiple of chunk_steps "
                f"({self.chunk_steps})"
            )
        if self.weight_decay < 0:
            problems.append(f"weight_decay must be at least 0, got {self.weight_decay}")
        if self.optimiser not in OPTIMISERS:
            problems.append(f"optimiser must be one of {', '.join(OPTIMISERS)}, got {self.optimiser!r}")
        return problems

    def validate(self) -> None:
        if problems := self.problems():
            raise TrainingError(f"invalid schedule {self}: " + "; ".join(problems))


def rescheduled(recipe: R, **changes: Any) -> R:
    """`recipe` (any recipe holding a `schedule`) with those fields of its schedule changed."""
    holder: Any = recipe  # any recipe dataclass that holds a `schedule`
    return typing.cast(R, dataclasses.replace(holder, schedule=dataclasses.replace(holder.schedule, **changes)))
