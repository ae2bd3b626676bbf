"""Table I row "Ours": CLIP-Adapters trained on the training split's features, on a frozen backbone.

Training featurizes the training split with the frozen backbone (cached, shared with `ocplace
featurize` and w/o LLM) and trains the adapters on it (`methods/ours/train.py`); the run loads as the
placement policy with those adapters.
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ocplace.methods.contract import LoadContext, MethodSpec, TrainContext
from ocplace.methods.ours.recipe import OursRecipe as Recipe
from ocplace.methods.policy_method import PolicyMethod, policy_of, prepare_train_features, trained_run_weights

if TYPE_CHECKING:
    from ocplace.models.parsing.types import Parser
    from ocplace.models.policy import PlacementPolicy


def train(ctx: TrainContext[Recipe]) -> Path:
    """Featurize the training split, then train the adapters into `ctx.out_dir` (resumable)."""
    from ocplace.methods.ours.train import train_ours
    from ocplace.models.backbone import load_backbone
    from ocplace.models.features import featurize_split, load_features

    backbone = load_backbone(ctx.backbone)
    features = load_features(featurize_split(Path(ctx.dataset_dir), "train", backbone), backbone.fingerprint)
    train_ours(features, ctx.out_dir, ctx.recipe, ctx.seed, ctx.fraction)
    return Path(ctx.out_dir)


def load_as(name: str, ctx: LoadContext) -> PolicyMethod:
    """Loads a run of a method that trains as Ours does, under its own name (`ours`, `ours_paper`)."""
    adapters_file = trained_run_weights(ctx.run_dir, "adapters", name)
    return PolicyMethod(name, policy_of(ctx, adapters_file, name), ctx.backbone, adapters_file)


def placement_policy(
    adapters_file: Path | None, backbone: str | None, parser: Parser, **policy_fields: Any
) -> PlacementPolicy:
    """Ours on one scene outside the benchmark (`ocplace place`): with these adapters on the backbone they were
    trained on (`backbone` when given), or zero-shot, as w/o Adapter, without them."""
    from ocplace.methods.export import backbone_of
    from ocplace.models.backbone import load_backbone
    from ocplace.models.policy import PlacementPolicy
    from ocplace.models.trained_adapters import load_adapters

    if adapters_file is None:
        return PlacementPolicy.from_run(load_backbone(backbone or "offline"), None, parser=parser, **policy_fields)
    adapters = load_adapters(adapters_file)  # a bad file fails before the backbone
    run_dir = adapters_file if adapters_file.is_dir() else adapters_file.parent  # its training's record is beside it
    spec = backbone_of(adapters, backbone, run_dir)
    return PlacementPolicy.from_run(load_backbone(spec), adapters, parser=parser, **policy_fields)


# A partial of a module-level function: specs travel to worker processes by pickle.
load = functools.partial(load_as, "ours")


SPEC: MethodSpec[Recipe] = MethodSpec(
    "ours", "Ours", load=load, train=train, prepare=prepare_train_features, shares_test_features=True
)
