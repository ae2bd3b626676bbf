"""How a policy row places once it is trained, JAX-free: what an experiment sets per row (`inference.ROW.FIELD`).

A trained run is weights; how the placement policy turns their grounding probabilities into a placement is
a separate choice, made at evaluation time on the same run (as lerobot's policies carry an inference section
that `lerobot-eval` overrides). `InferenceSettings` holds that choice; its fields are `PlacementPolicy` fields
of the same names, so the policy, a policy folder's `config.json`, `describe()` and the stored evaluations'
keys all read one value. The sample count is the evaluation's (`--samples`), and the sampler's shape is the
design contract's (docs/placement.md): neither is set here.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Literal

from ocplace.errors import ConfigError
from ocplace.models.detection import DetectorConfig
from ocplace.serial import bounded
from ocplace.vocabulary import DECISION_MODES, MAX_PARSED_TUPLES, MAX_TOP_K

# The joint search enumerates top_k ** tuples assignments per scene; past this it refuses the settings.
MAX_ASSIGNMENTS = 4096


@dataclasses.dataclass(frozen=True)
class Decision:
    """Which visual token each parsed reference is grounded to.

    `argmax`: each reference at its own most probable token, then a placement is looked for (the paper).
    `joint`: among the `top_k` tokens of every reference, the assignment with the highest joint probability
    whose tuples admit a collision-free placement and in which references with different names take different
    objects (the same name, the same token); when none does, the argmax assignment, flagged
    (`models/joint_grounding.py`, docs/policy.md)."""

    mode: Literal["argmax", "joint"] = "argmax"
    # Rule J chose 5 on the dev splits for Ours and for w/o Adapter (docs/settings.md).
    top_k: int = bounded(5, 1, MAX_TOP_K, help="joint: candidate tokens per reference")

    def problems(self, max_tuples: int = MAX_PARSED_TUPLES) -> list[str]:
        problems = []
        if self.mode not in DECISION_MODES:
            problems.append(f"decision.mode must be one of {', '.join(DECISION_MODES)}, got {self.mode!r}")
        if not isinstance(self.top_k, int) or not 1 <= self.top_k <= MAX_TOP_K:
            problems.append(f"decision.top_k must be an integer from 1 to {MAX_TOP_K}, got {self.top_k!r}")
        elif self.mode == "joint" and self.top_k**max_tuples > MAX_ASSIGNMENTS:
            problems.append(
                f"decision.top_k {self.top_k} with up to {max_tuples} tuples gives {self.top_k**max_tuples:,} "
                f"assignments per scene, past the joint search's {MAX_ASSIGNMENTS:,}: lower top_k or max_tuples"
            )
        return problems


# The robot's decision (`PlacementPolicy`'s default, `ocplace place`, the policy folders `reproduce` and `export`
# write): the joint one, which rule J made the default on the dev splits (docs/settings.md). Table I's paper rows keep
# the paper's argmax (their `INFERENCE`).
ROBOT_DECISION = Decision("joint")


@dataclasses.dataclass(frozen=True)
class InferenceSettings:
    """A policy row's placement-time settings; each field is the `PlacementPolicy` field of its name."""

    decision: Decision = Decision()
    max_tuples: int = dataclasses.field(
        default=MAX_PARSED_TUPLES, metadata={"help": "most tuples an instruction may parse into"}
    )
    detector: DetectorConfig = DetectorConfig()

    def problems(self) -> list[str]:
        problems = self.decision.problems(self.max_tuples)
        if not isinstance(self.max_tuples, int) or not 1 <= self.max_tuples <= MAX_PARSED_TUPLES:
            problems.append(f"max_tuples must be an integer from 1 to {MAX_PARSED_TUPLES}, got {self.max_tuples!r}")
        return problems

    def validate(self) -> None:
        problems = self.problems()
        if problems:
            raise ConfigError("invalid inference settings: " + "; ".join(problems))

    def policy_fields(self) -> dict[str, Any]:
        """The `PlacementPolicy` fields these settings set, by name."""
        return {field.name: getattr(self, field.name) for field in dataclasses.fields(self)}
