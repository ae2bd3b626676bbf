"""Row "Ours, joint inference" (beyond the paper): Ours' trained runs, placed with the joint, feasibility-aware
decision (`models/joint_grounding.py`) instead of an argmax per reference. It trains nothing: `reproduce` trains
Ours' runs for it, and its evaluations read the test features Ours' encoded."""

import functools

from ocplace.methods.contract import MethodSpec
from ocplace.methods.ours import method as ours

SPEC: MethodSpec[None] = MethodSpec(
    "ours_joint",
    "Ours, joint inference (beyond the paper)",
    load=functools.partial(ours.load_as, "ours_joint"),
    places_with="ours",
    shares_test_features=True,
)
