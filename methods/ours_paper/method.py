"""Row "Ours, paper's adapters": Ours trained and blended as the paper does (residual ratio 0.2 on both towers,
A(x) unnormalised, no regulariser), beside Ours with the adapters rule A chose (docs/settings.md). Same
training and loading as Ours (`methods/ours/method.py`); only the recipe differs."""

from __future__ import annotations

import functools

from ocplace.methods.contract import MethodSpec
from ocplace.methods.ours import method as ours
from ocplace.methods.ours.recipe import OursRecipe as Recipe
from ocplace.methods.policy_method import prepare_train_features

SPEC: MethodSpec[Recipe] = MethodSpec(
    "ours_paper",
    "Ours, paper's adapters",
    load=functools.partial(ours.load_as, "ours_paper"),
    train=ours.train,
    prepare=prepare_train_features,
    shares_test_features=True,
)
