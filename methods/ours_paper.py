"""Row "Ours, paper's adapters": Ours trained and blended as the paper does (residual ratio 0.2 on both towers,
A(x) unnormalised, no regulariser), beside Ours with the adapters rule A chose (docs/settings.md). Same
training and loading as Ours (`methods/ours.py`); only the recipe differs."""

from __future__ import annotations

from ocplace.methods import ours
from ocplace.methods.api import LoadContext, MethodSpec
from ocplace.methods.policy_method import PolicyMethod, policy_of, prepare_train_features, trained_run_weights
from ocplace.train.config import TrainConfig as Recipe


def load(ctx: LoadContext) -> PolicyMethod:
    adapters_file = trained_run_weights(ctx.run_dir, "adapters", "ours_paper")
    return PolicyMethod("ours_paper", policy_of(ctx, adapters_file), ctx.backbone, adapters_file)


SPEC: MethodSpec[Recipe] = MethodSpec(
    "ours_paper",
    "Ours, paper's adapters",
    load=load,
    train=ours.train,
    prepare=prepare_train_features,
    shares_test_features=True,
)
