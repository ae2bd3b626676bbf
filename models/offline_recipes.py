"""Pretraining recipes of the offline backbone: what is rendered, how the towers are trained, and
where the result goes.

`default` is the recipe `load_backbone("offline")` loads (<= 30 min on 2 CPU cores, rendering
included): the foundation backbone, pretrained on the furniture corpus under the `open` protocol;
`strict` the same under the `strict` protocol; `task` the earlier backbone, pretrained on the
benchmark's training objects; `demo` a few-minute version of `default` for `make demo`, `smoke` a
seconds-long one for tests.
A recipe's result lives in `<cache>/backbones/offline-<hash of its config>/`: the hash covers every
setting, so the loader finds a recipe's backbone by its name alone, and `train.pretrain` builds it.
"""

from __future__ import annotations

import dataclasses
import hashlib
from pathlib import Path
from typing import ClassVar

from ocplace import serial
from ocplace.errors import TrainingError
from ocplace.models import offline_config
from ocplace.models.offline_config import OfflineConfig
from ocplace.paths import backbones_cache
from ocplace.sim.colour_terms import BASIC_COLOURS, COLOUR_TERMS
from ocplace.sim.corpus.cutout_sources import CUTOUT_SOURCES
from ocplace.sim.corpus.selection import PROTOCOLS
from ocplace.vocabulary import SHAPES, SIZES

POOLS = ("corpus", "task")
BALANCES = ("class", "group")
LARGE_MODELS = ("drop", "shrink")


@dataclasses.dataclass(frozen=True)
class RenderConfig:
    """Scenes of the pool's objects and named primitives on seen table textures, how crops are cut from
    them, and how objects are recoloured.

    `pool`: `corpus` renders the furniture corpus (`sim/corpus/`), never a benchmark object: the
    foundation backbone. `task` renders the benchmark's training objects: the backbone of earlier
    results, kept to compare with.
    """

    pool: str = "corpus"
    protocol: str = "open"  # corpus: "open" keeps every model of the rule, "strict" drops test-noun names
    # Corpus categories (head-noun groups naming no benchmark object) held out of pretraining, by a seeded hash,
    # to choose settings on; validation scenes show at most `validation_cap` models of one category.
    validation_share: float = 0.2
    validation_seed: int = 0
    validation_cap: int = 3
    scenes: int = 800
    objects_per_scene: int = 5  # as in the benchmark: occlusions come with the drops
    renders_per_scene: int = 2  # extra renders of a settled scene under new lighting and table colours
    max_objects: int = 0  # > 0: only the first `max_objects` objects of the pool (smoke tests)
    crop_size: int = 224  # the benchmark loader's crop size, before the backbone's own resize
    padding: float = 0.1  # the pipeline's crop padding (`sim.boxes.square_crop`)
    canonical_share: float = 0.5  # share of crops cut exactly as the pipeline cuts them
    padding_range: tuple[float, float] = (0.0, 0.3)  # jittered crops draw their padding from here
    shift: float = 0.08  # jittered crops move the box by up to this share of its size
    light_range: tuple[float, float] = (0.55, 1.25)  # scale of the headlight and the top light
    light_tilt: float = 0.6  # largest tilt (rad) of the top light away from its default direction
    table_jitter: float = 0.5  # probability that a render recolours the table pixels
    # Probability that an object of a render also gives a crop recoloured to one of `colours`
    # (its own class: "a blue bowl"); its plain crop is kept.
    recolour_share: float = 0.3
    colours: tuple[str, ...] = BASIC_COLOURS  # colour terms of recoloured objects and of primitives
    # `seen`: a recoloured object whose captions would name a test object ("a yellow bowl") is left out;
    # `open` (corpus pool, `open` protocol only): corpus objects keep such colour-category captions, as
    # CLIP's data holds yellow bowls.
    colour_captions: str = "seen"
    # `drop`: tabletop corpus models only; `shrink` (corpus pool): also the large tier (chairs, beds, cars, ...),
    # shrunk to tabletop size as every model is (`sim.corpus.build`), for more categories.
    large_models: str = "drop"
    # Cut-out sources (corpus pool) whose images are rendered as thin textured cut-outs, for more named
    # categories: "stamps" (Tux Paint's), "emoji" (Fluent Emoji 3-D); () none.
    cutouts: tuple[str, ...] = ()
    primitives_per_scene: int = 2  # named primitives dropped with the objects; 0: no primitive classes
    primitive_shapes: tuple[str, ...] = SHAPES
    primitive_widths: tuple[float, ...] = (0.05, 0.075, 0.10)  # m, small, medium and large primitives
    chunk_scenes: int = 50  # scenes per resumable render chunk
    seed: int = 0

    def serial_omitted(self) -> tuple[str, ...]:
        """`large_models` and `cutouts` at their defaults stay out of the recipe's text, so recipes from before them
        keep their key."""
        return tuple(name for name in ("large_models", "cutouts") if getattr(self, name) in ("drop", ()))

    def problems(self) -> list[str]:
        """What is wrong with these settings (`PretrainConfig.validate` raises with them)."""
        problems = []
        if self.pool not in POOLS:
            problems.append(f"pool must be one of {', '.join(POOLS)}")
        if self.protocol not in PROTOCOLS:
            problems.append(f"protocol must be one of {', '.join(PROTOCOLS)}")
        if not 0.0 <= self.validation_share < 1.0:
            problems.append("validation_share must be in [0, 1)")
        if self.validation_cap < 1:
            problems.append("validation_cap must be positive")
        if self.scenes < 1 or self.renders_per_scene < 1 or self.chunk_scenes < 1:
            problems.append("scenes, renders_per_scene and chunk_scenes must be positive")
        if self.objects_per_scene < 1:
            problems.append("objects_per_scene must be positive")
        if not all(0.0 <= p <= 1.0 for p in (self.canonical_share, self.table_jitter, self.recolour_share)):
            problems.append("canonical_share, table_jitter and recolour_share are probabilities")
        if self.colour_captions not in ("seen", "open") or (
            self.colour_captions == "open" and (self.pool, self.protocol) != ("corpus", "open")
        ):
            problems.append("colour_captions is 'seen', or 'open' with the corpus pool under the open protocol")
        if self.large_models not in LARGE_MODELS or (self.large_models == "shrink" and self.pool != "corpus"):
            problems.append(f"large_models is one of {', '.join(LARGE_MODELS)}; 'shrink' needs the corpus pool")
        if not set(self.cutouts) <= set(CUTOUT_SOURCES) or (self.cutouts and self.pool != "corpus"):
            problems.append(f"cutouts are among {', '.join(CUTOUT_SOURCES)}, and need the corpus pool")
        if not self.colours or not set(self.colours) <= set(COLOUR_TERMS):
            problems.append(f"colours must be among {', '.join(COLOUR_TERMS)}")
        if not 0 <= self.primitives_per_scene <= len(SIZES) * len(self.primitive_shapes) or not set(
            self.primitive_shapes
        ) <= set(SHAPES):
            problems.append(
                f"primitives_per_scene must be in [0, {len(SIZES)} x the number of primitive_shapes] "
                f"and primitive_shapes among {', '.join(SHAPES)}"
            )
        if (
            len(self.primitive_widths) != len(SIZES)
            or list(self.primitive_widths) != sorted(self.primitive_widths)
            or min(self.primitive_widths) <= 0
        ):
            problems.append(f"primitive_widths: {len(SIZES)} increasing positive widths ({', '.join(SIZES)})")
        return problems


@dataclasses.dataclass(frozen=True)
class OptimConfig:
    optimiser: ClassVar[str] = "adamw_clipped"  # decaying to a share of the peak (`train/optim.make`)

    steps: int = 700
    batch_size: int = 64
    table_share: float = 1 / 16  # share of each batch that is whole-workspace images ("a table")
    # how the other images divide among the kinds of class (renormalised over the kinds rendered)
    kind_shares: tuple[tuple[str, float], ...] = (("object", 0.5), ("recoloured", 0.25), ("primitive", 0.25))
    # Within a kind, a class uniformly (`class`), or a category group uniformly and then one of its classes
    # (`group`: 33 near-identical wall plugs, switches and sockets weigh as one category, not as 33).
    balance: str = "class"
    learning_rate: float = 1e-3
    warmup_steps: int = 50
    weight_decay: float = 0.05
    max_logit_scale: float = 100.0  # CLIP's clamp on the learned temperature
    rotate: bool = True  # random quarter turns and flips: the camera looks straight down
    colour_jitter: float = 0.1  # brightness/contrast/saturation jitter amplitude
    checkpoint_every: int = 100
    keep_checkpoints: int = 2
    seed: int = 0

    def problems(self) -> list[str]:
        """What is wrong with these settings (`PretrainConfig.validate` raises with them)."""
        problems = []
        if self.steps < 1 or self.batch_size < 2 or self.checkpoint_every < 1 or self.keep_checkpoints < 1:
            problems.append("steps, checkpoint_every and keep_checkpoints must be positive, batch_size >= 2")
        if not 0.0 <= self.table_share < 1.0:
            problems.append("table_share must be in [0, 1)")
        if self.balance not in BALANCES:
            problems.append(f"balance must be one of {', '.join(BALANCES)}")
        if (
            not self.kind_shares
            or any(share < 0 for _, share in self.kind_shares)
            or not any(kind == "object" and share > 0 for kind, share in self.kind_shares)
        ):
            problems.append("kind_shares needs a positive share for 'object' and no negative share")
        return problems


@dataclasses.dataclass(frozen=True)
class PretrainConfig:
    recipe: str
    model: OfflineConfig = offline_config.default_config()
    render: RenderConfig = RenderConfig()
    optim: OptimConfig = OptimConfig()

    def validate(self) -> None:
        problems = self.render.problems() + self.optim.problems()
        if problems:
            raise TrainingError(f"invalid pretraining recipe {self.recipe!r}: " + "; ".join(problems))

    def key(self) -> str:
        """12 hex digits that change with any setting."""
        return hashlib.sha256(serial.to_json(self).encode()).hexdigest()[:12]


# Rule C of docs/settings.md kept colour-category captions for recoloured corpus objects under `open`.
OPEN_RENDER = RenderConfig(colour_captions="open")


def default_config() -> PretrainConfig:
    """The foundation backbone: the furniture corpus under the `open` protocol, never a benchmark object."""
    return PretrainConfig("default", render=OPEN_RENDER)


def strict_config() -> PretrainConfig:
    """The default without the corpus models whose names hold a test object's noun (`strict`)."""
    return PretrainConfig("strict", render=RenderConfig(protocol="strict"))


def task_config() -> PretrainConfig:
    """The backbone of the results before the corpus: renders of the benchmark's training objects."""
    return PretrainConfig("task", render=RenderConfig(pool="task"))


def demo_config() -> PretrainConfig:
    """A few minutes on 2 cores: fewer scenes and steps, same architecture and corpus."""
    return PretrainConfig(
        "demo",
        render=dataclasses.replace(OPEN_RENDER, scenes=100),
        optim=OptimConfig(steps=75, warmup_steps=8, checkpoint_every=25),
    )


def smoke_config() -> PretrainConfig:
    """Seconds: a tiny tower, four corpus models, two scenes, a few steps."""
    return PretrainConfig(
        "smoke",
        model=offline_config.smoke_config(),
        # No primitives: the smoke run's scenes hold pool objects only (a test checks every scene it
        # builds against the pool); `tests/test_pretrain_data.py` turns them on.
        render=RenderConfig(
            scenes=2,
            objects_per_scene=3,
            renders_per_scene=2,
            max_objects=4,
            chunk_scenes=1,
            recolour_share=0.5,
            colours=("red", "green", "blue", "white"),
            primitives_per_scene=0,
            primitive_shapes=("box", "cylinder", "ring"),
        ),
        optim=OptimConfig(
            steps=12, batch_size=16, table_share=0.125, learning_rate=3e-3, warmup_steps=2, checkpoint_every=4
        ),
    )


RECIPES = {
    "default": default_config,
    "strict": strict_config,
    "task": task_config,
    "demo": demo_config,
    "smoke": smoke_config,
}


def recipe_config(name: str) -> PretrainConfig:
    if name not in RECIPES:
        raise TrainingError(f"unknown pretraining recipe {name!r}; choose one of {', '.join(RECIPES)}")
    return RECIPES[name]()


def output_dir(config: PretrainConfig) -> Path:
    """The recipe's key, and, when the library's pools are not the benchmark's (objects added with `assets build
    --gso`), a digest of what differs: a backbone pretrained on another pool is another model (docs/library.md)."""
    from ocplace.sim.library.library import added_objects_digest

    added = added_objects_digest()
    return backbones_cache() / (f"offline-{config.key()}" + (f"-pool{added}" if added else ""))


def recipe_dir(name: str) -> Path:
    """Where the named recipe's backbone is (or will be) saved."""
    return output_dir(recipe_config(name))
