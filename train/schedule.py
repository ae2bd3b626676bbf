"""A training budget without JAX (`Schedule`), so the recipes that hold one (each row's `recipe.py`) build and
check before JAX is imported and a bad `--set` fails at once."""

from __future__ import annotations

import dataclasses

from ocplace.errors import TrainingError


@dataclasses.dataclass(frozen=True)
class Schedule:
    """Optimisation budget of a recipe: Adam, linear warm-up then cosine decay to 0 (`train/optim.make`)."""

    steps: int
    batch_size: int
    learning_rate: float
    warmup_steps: int
    chunk_steps: int  # steps fused into one jitted lax.scan call
    checkpoint_every: int  # a multiple of chunk_steps
    keep_checkpoints: int = 2

    def validate(self) -> None:
        if (
            min(self.steps, self.batch_size, self.chunk_steps, self.keep_checkpoints) < 1
            or self.checkpoint_every % self.chunk_steps
        ):
            raise TrainingError(f"invalid schedule {self}: positive sizes, checkpoint_every a multiple of chunk_steps")
