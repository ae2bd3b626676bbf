"""Table I row "Ours w/o Adapter": Ours' policy grounding by plain backbone similarity; it learns nothing."""

from __future__ import annotations

from ocplace.methods.contract import LoadContext, MethodSpec
from ocplace.methods.policy_method import PolicyMethod, policy_of


def load(ctx: LoadContext) -> PolicyMethod:
    return PolicyMethod("no_adapter", policy_of(ctx, None), ctx.backbone, None)


SPEC: MethodSpec[None] = MethodSpec("no_adapter", "Ours w/o Adapter", load=load, shares_test_features=True)
