"""Table I row "Ours": CLIP-Adapters trained on the training split's features, on a frozen backbone.

Training featurizes the training split with the frozen backbone (cached, shared with `ocplace
featurize` and w/o LLM) and trains the adapters on it (`train/ours.py`); the run loads as the
placement policy with those adapters.
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path

from ocplace.methods.api import LoadContext, MethodSpec, TrainContext
from ocplace.methods.policy_method import PolicyMethod, policy_of, prepare_train_features, trained_run_weights
from ocplace.train.config import TrainConfig as Recipe


def train(ctx: TrainContext[Recipe]) -> Path:
    """Featurize the training split, then train the adapters into `ctx.out_dir` (resumable)."""
    from ocplace.models.backbone import load_backbone
    from ocplace.models.features import featurize_split, load_features
    from ocplace.train.ours import train_ours

    backbone = load_backbone(ctx.backbone)
    features = load_features(featurize_split(Path(ctx.dataset_dir), "train", backbone), backbone.fingerprint)
    train_ours(features, ctx.out_dir, dataclasses.replace(ctx.recipe, fraction=ctx.fraction, seed=ctx.seed))
    return Path(ctx.out_dir)


def load_as(name: str, ctx: LoadContext) -> PolicyMethod:
    """Loads a run of a method that trains as Ours does, under its own name (`ours`, `ours_paper`)."""
    adapters_file = trained_run_weights(ctx.run_dir, "adapters", name)
    return PolicyMethod(name, policy_of(ctx, adapters_file), ctx.backbone, adapters_file)


# A partial of a module-level function: specs travel to worker processes by pickle.
load = functools.partial(load_as, "ours")


SPEC: MethodSpec[Recipe] = MethodSpec(
    "ours", "Ours", load=load, train=train, prepare=prepare_train_features, shares_test_features=True
)
