"""Row "Ours w/o Adapter, joint inference" (beyond the paper): w/o Adapter's zero-shot policy with the joint,
feasibility-aware decision (`models/joint_grounding.py`). It learns nothing, like w/o Adapter."""

import functools

from ocplace.methods.contract import MethodSpec
from ocplace.methods.no_adapter import method as no_adapter

SPEC: MethodSpec[None] = MethodSpec(
    "no_adapter_joint",
    "Ours w/o Adapter, joint inference (beyond the paper)",
    load=functools.partial(no_adapter.load_as, "no_adapter_joint"),
    shares_test_features=True,
)
