"""Table I row "Ours w/o Adapter": Ours' policy grounding by plain backbone similarity; it learns nothing."""

from __future__ import annotations

import functools

from ocplace.methods.contract import LoadContext, MethodSpec
from ocplace.methods.policy_method import PolicyMethod, policy_of


def load_as(name: str, ctx: LoadContext) -> PolicyMethod:
    """The zero-shot policy under the name of a row that places as w/o Adapter does (`no_adapter`, its variants)."""
    return PolicyMethod(name, policy_of(ctx, None, name), ctx.backbone, None)


load = functools.partial(load_as, "no_adapter")  # a partial of a module-level function: specs travel by pickle

SPEC: MethodSpec[None] = MethodSpec("no_adapter", "Ours w/o Adapter", load=load, shares_test_features=True)
