"""The training recipes of the methods that learn, without JAX: an experiment holds one per method
(`Experiment.recipes`), so it is built and checked before JAX is imported and a bad `--set` fails at
once. Ours' recipe is `train/config.py`'s `TrainConfig`; each method's training is its module here.
"""

from __future__ import annotations

import dataclasses

from ocplace.errors import TrainingError
from ocplace.models.baselines.cliport_config import CliportConfig
from ocplace.models.baselines.grid_config import GridConfig
from ocplace.models.no_llm_config import NoLlmConfig
from ocplace.models.no_pretrain_config import NoPretrainConfig


@dataclasses.dataclass(frozen=True)
class Schedule:
    """Optimisation budget of a recipe: Adam, linear warm-up then cosine decay to 0."""

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

    def learning_rate_schedule(self):
        """`optim.warmup_cosine` of this budget (an optax schedule)."""
        from ocplace.train import optim  # JAX behind it: this module stays light

        return optim.warmup_cosine(self.learning_rate, self.warmup_steps, self.steps)

    def optimizer(self):
        """`train/optim.py`'s Adam on this learning-rate schedule."""
        from ocplace.train import optim

        return optim.adam(self.learning_rate_schedule())


@dataclasses.dataclass(frozen=True)
class NoLlmTrainConfig:
    steps: int = 10_000
    batch_size: int = 32
    learning_rate: float = 1e-3  # Adam peak, linear warm-up then cosine decay to 0
    warmup_steps: int = 500
    relation_weight: float = 1.0  # loss = reference CE + relation_weight * relation CE
    hidden: int = 256  # relation MLP width
    reduction: int = 4
    residual_ratio: float = 0.2
    seed: int = 0  # initial weights and example order
    fraction: float = 1.0
    subset_seed: int = 0  # nested subsets, as train.ours
    chunk_steps: int = 1_000
    checkpoint_every: int = 5_000
    keep_checkpoints: int = 2

    def validate(self) -> None:
        if self.steps < 1 or self.batch_size < 1 or self.chunk_steps < 1:
            raise TrainingError("steps, batch_size and chunk_steps must be positive")
        if not 0.0 < self.fraction <= 1.0:
            raise TrainingError(f"fraction must be in (0, 1], got {self.fraction}")
        if self.checkpoint_every % self.chunk_steps:
            raise TrainingError("checkpoint_every must be a multiple of chunk_steps")

    def model_config(self, dim: int) -> NoLlmConfig:
        return NoLlmConfig(dim=dim, reduction=self.reduction, residual_ratio=self.residual_ratio, hidden=self.hidden)


@dataclasses.dataclass(frozen=True)
class NoPretrainTrainConfig:
    steps: int = 600  # 28,800 crops through the trunk: ~10 min on 2 cores at 128 px
    batch_size: int = 8  # scenes per step (each with all its visual tokens)
    learning_rate: float = 1e-3  # AdamW peak; linear warm-up, cosine decay to 2% (as the backbone pretraining)
    warmup_steps: int = 50
    weight_decay: float = 0.05  # matrices only
    augment: bool = True  # a random symmetry of the square per image
    seed: int = 0
    fraction: float = 1.0
    subset_seed: int = 0
    log_every: int = 50
    checkpoint_every: int = 200
    keep_checkpoints: int = 2

    def validate(self) -> None:
        if min(self.steps, self.batch_size, self.log_every, self.checkpoint_every) < 1:
            raise TrainingError("steps, batch_size, log_every and checkpoint_every must be positive")
        if not 0.0 < self.fraction <= 1.0:
            raise TrainingError(f"fraction must be in (0, 1], got {self.fraction}")


@dataclasses.dataclass(frozen=True)
class NoPretrainRecipe:
    model: NoPretrainConfig
    train: NoPretrainTrainConfig


@dataclasses.dataclass(frozen=True)
class GridsRecipe:
    grid: GridConfig
    schedule: Schedule


@dataclasses.dataclass(frozen=True)
class CliportRecipe:
    network: CliportConfig
    schedule: Schedule
    num_targets: int = 16  # feasible pixels cached per scene
