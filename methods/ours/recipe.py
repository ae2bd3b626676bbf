"""Ours' training recipe (`OursRecipe`), without JAX: its adapters, its schedule, and what only Ours sets."""

from __future__ import annotations

import dataclasses

from ocplace.errors import TrainingError
from ocplace.models.adapter_settings import AdapterSettings
from ocplace.serial import bounded
from ocplace.train.schedule import Schedule

# The paper's budget: 200K steps at batch 1 on the 2000 training scenes (100 epochs), Adam with a linear warm-up
# to 1e-4, then cosine decay to 0.
PAPER_SCHEDULE = Schedule(
    steps=200_000, batch_size=1, learning_rate=1e-4, warmup_steps=1_000, chunk_steps=2_000, checkpoint_every=50_000
)


@dataclasses.dataclass(frozen=True)
class OursRecipe:
    """The defaults are the paper's adapters and budget; `default_config()` is Ours' recipe (rule A's adapters)."""

    adapters: AdapterSettings = AdapterSettings()
    schedule: Schedule = PAPER_SCHEDULE
    # A pull of the adapted features toward the backbone's own (KgCoOp's idea for prompts; 0: the paper's):
    # anchor x the mean squared distance of x* from x.
    anchor: float = bounded(
        0.0, 0.0, 1000.0, help="weight of a pull of the adapted features toward the backbone's (0: none)"
    )
    logit_scale: float | None = bounded(
        None, 1e-3, 1000.0, help="grounding logit scale; none means the backbone's own, from the feature file"
    )
    eval_every: int = bounded(
        10_000, 1, 10_000_000, help="steps between grounding accuracies on the training subset (and --val-features)"
    )
    # Fixed apart from the run's seed, so a 25% subset is part of the 50% one.
    subset_seed: int = bounded(0, 0, 2**32 - 1, help="draws the --fraction subsets, nested")

    def validate(self) -> None:
        problems = self.schedule.problems() + self.adapters.problems()
        if self.logit_scale is not None and self.logit_scale <= 0:  # finite: `number_problems`, as every number
            problems.append(f"logit_scale must be positive (or none), got {self.logit_scale}")
        if self.anchor < 0:
            problems.append(f"anchor must be at least 0, got {self.anchor}")
        chunk_steps = max(self.schedule.chunk_steps, 1)
        if self.eval_every < 1 or self.eval_every % chunk_steps:
            problems.append(f"eval_every ({self.eval_every}) must be a positive multiple of chunk_steps {chunk_steps}")
        if self.subset_seed < 0:
            problems.append(f"subset_seed must be at least 0, got {self.subset_seed}")
        if problems:
            raise TrainingError("invalid training configuration: " + "; ".join(problems))


def chosen_adapters(recipe: OursRecipe) -> OursRecipe:
    """`recipe` with the adapters rule A chose (docs/settings.md; on `dev_seen`, `dev_colour` and the corpus'
    held-out categories, never a test subset): A(x) scaled to the norm of x, the visual adapter 0.1 of the blend
    and the text adapter 0.5."""
    adapters = dataclasses.replace(recipe.adapters, normalise=True, residual_ratio=0.1, text_ratio=0.5)
    return dataclasses.replace(recipe, adapters=adapters)


def default_config() -> OursRecipe:
    """Ours: the paper's budget with the chosen adapters."""
    return chosen_adapters(OursRecipe())


def paper_config() -> OursRecipe:
    """The paper's adapters (CLIP-Adapter's residual ratio 0.2 on both towers, A(x) as it comes, no regulariser):
    the class's defaults, the row "Ours, paper's adapters"."""
    return OursRecipe()


def smoke_config() -> OursRecipe:
    """A few hundred steps: enough to fit a tiny synthetic problem in tests."""
    schedule = Schedule(
        steps=300, batch_size=1, learning_rate=1e-2, warmup_steps=10, chunk_steps=50, checkpoint_every=100
    )
    return OursRecipe(schedule=schedule, eval_every=100)


def demo_paper_config() -> OursRecipe:
    """`make demo`'s budget with the paper's adapters: a tenth of the paper's steps at a higher peak rate (the demo
    dataset is small too)."""
    schedule = dataclasses.replace(
        PAPER_SCHEDULE, steps=20_000, learning_rate=5e-4, warmup_steps=500, checkpoint_every=10_000
    )
    return OursRecipe(schedule=schedule, eval_every=10_000)


# The recipe of each row trained as Ours is, at each experiment's scale (configs/<name>.py): "ours" with the
# adapters rule A chose, "ours_paper" with the paper's.
PRESETS = {
    "default": default_config(),
    "demo": chosen_adapters(demo_paper_config()),
    "smoke": chosen_adapters(smoke_config()),
}
PAPER_PRESETS = {"default": paper_config(), "demo": demo_paper_config(), "smoke": smoke_config()}
