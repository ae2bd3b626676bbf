"""Training configuration for the grounding adapters."""

from __future__ import annotations

import dataclasses

from ocplace.errors import TrainingError


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """The defaults are the paper's adapters and budget; `default_config()` is Ours' recipe (rule A's adapters)."""

    # The paper's budget: 200K steps at batch 1 on the 2000 training scenes (100 epochs).
    steps: int = 200_000
    batch_size: int = 1
    # Adam (train/optim.py) with a linear warm-up from 0 to `learning_rate`, then cosine decay to 0.
    learning_rate: float = dataclasses.field(default=1e-4, metadata={"help": "peak learning rate"})
    warmup_steps: int = 1_000
    seed: int = 0  # adapter initialisation and example order
    fraction: float = dataclasses.field(
        default=1.0, metadata={"help": "train on this seeded share of the scenes (sample-efficiency curve)"}
    )
    subset_seed: int = 0  # fixed apart from `seed`, so a 25% subset is part of the 50% one
    reduction: int = 4  # adapter hidden width = D / reduction
    residual_ratio: float = 0.2  # the adapter's weight in the blend: the visual tower's, and the text's unless set
    text_ratio: float | None = dataclasses.field(
        default=None, metadata={"help": "the text adapter's own weight in the blend; none: residual_ratio"}
    )
    normalise: bool = dataclasses.field(
        default=False, metadata={"help": "scale A(x) to the norm of x before the blend (models/adapters.py)"}
    )
    # Regularisers (0: the paper's adapters): decoupled weight decay, and a pull of the adapted features toward
    # the backbone's own (KgCoOp's idea for prompts): anchor x the mean squared distance of x* from x.
    weight_decay: float = 0.0
    anchor: float = 0.0
    logit_scale: float | None = dataclasses.field(
        default=None, metadata={"help": "grounding logit scale; none means the backbone's own, from the feature file"}
    )
    chunk_steps: int = 2_000  # steps fused into one jitted lax.scan call
    eval_every: int = 10_000  # grounding accuracy on the training subset (and validation set)
    checkpoint_every: int = 50_000
    keep_checkpoints: int = 2

    def validate(self) -> None:
        problems = []
        if self.steps < 1 or self.batch_size < 1 or self.chunk_steps < 1:
            problems.append("steps, batch_size and chunk_steps must be positive")
        if self.logit_scale is not None and self.logit_scale <= 0:  # finite: `number_problems`, as every number
            problems.append(f"logit_scale must be positive (or none), got {self.logit_scale}")
        if not 0.0 < self.fraction <= 1.0:
            problems.append(f"fraction must be in (0, 1], got {self.fraction}")
        for name in ("residual_ratio", "text_ratio"):
            value = getattr(self, name)
            if value is not None and not 0.0 <= value <= 1.0:
                problems.append(f"{name} must be in [0, 1], got {value}")
        if self.weight_decay < 0 or self.anchor < 0:
            problems.append(f"weight_decay and anchor must be at least 0, got {self.weight_decay}, {self.anchor}")
        for name in ("eval_every", "checkpoint_every"):
            value = getattr(self, name)
            if value < 1 or value % max(self.chunk_steps, 1):
                problems.append(f"{name} ({value}) must be a positive multiple of chunk_steps ({self.chunk_steps})")
        if self.keep_checkpoints < 1:
            problems.append("keep_checkpoints must be at least 1")
        if self.reduction < 1:
            problems.append(f"reduction must be at least 1 (hidden width = D / reduction), got {self.reduction}")
        if self.seed < 0 or self.subset_seed < 0:
            problems.append(f"seed and subset_seed must be at least 0, got {self.seed}, {self.subset_seed}")
        if problems:
            raise TrainingError("invalid training configuration: " + "; ".join(problems))

    @property
    def adapters(self) -> dict[str, object]:
        """The `AdapterConfig` fields this recipe sets (the width comes from the features)."""
        return {
            "reduction": self.reduction,
            "residual_ratio": self.residual_ratio,
            "text_ratio": self.text_ratio,
            "normalise": self.normalise,
        }


def chosen_adapters(config: TrainConfig) -> TrainConfig:
    """`config` with the adapters rule A chose (docs/settings.md; on `dev_seen`, `dev_colour` and the corpus'
    held-out categories, never a test subset): A(x) scaled to the norm of x, the visual adapter 0.1 of the blend
    and the text adapter 0.5."""
    return dataclasses.replace(config, normalise=True, residual_ratio=0.1, text_ratio=0.5)


def default_config() -> TrainConfig:
    """Ours: the paper's budget with the chosen adapters."""
    return chosen_adapters(TrainConfig())


def paper_config() -> TrainConfig:
    """The paper's adapters (CLIP-Adapter's residual ratio 0.2 on both towers, A(x) as it comes, no regulariser):
    the class's defaults, the row "Ours, paper's adapters"."""
    return TrainConfig()


def smoke_config() -> TrainConfig:
    """A few hundred steps: enough to fit a tiny synthetic problem in tests."""
    return TrainConfig(
        steps=300, learning_rate=1e-2, warmup_steps=10, chunk_steps=50, eval_every=100, checkpoint_every=100
    )
