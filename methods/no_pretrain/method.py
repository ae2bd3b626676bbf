"""Table I row "Ours w/o CLIP pre-train" (`methods/no_pretrain/model.py`, `methods/no_pretrain/train.py`).

The offline backbone's architecture at random initialisation, trained with the adapters on the
training split; at test time it is Ours' policy (parser, grounding, sampler) on that tower and those
adapters.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ocplace.methods.contract import LoadContext, MethodSpec, TrainContext
from ocplace.methods.no_pretrain.recipe import NoPretrainRecipe as Recipe
from ocplace.methods.policy_method import PolicyMethod, describe_policy, policy_settings, trained_run_weights
from ocplace.paths import read_run_file

if TYPE_CHECKING:
    from ocplace.models.offline_backbone import OfflineBackbone


def train(ctx: TrainContext[Recipe]) -> Path:
    """Train the tower and adapters from random weights (`ctx.backbone` is not used: nothing is pretrained)."""
    from ocplace.methods.no_pretrain import train as no_pretrain

    return no_pretrain.train_no_pretrain(
        Path(ctx.dataset_dir), Path(ctx.out_dir), ctx.recipe, ctx.seed, ctx.fraction, progress=True
    )


@dataclasses.dataclass
class NoPretrainMethod(PolicyMethod):
    run_dir: Path
    tower: OfflineBackbone  # the policy's backbone: the tower trained from random weights

    def describe(self) -> dict[str, Any]:
        described = describe_policy(self.policy, self.name, self.backbone_spec, self.adapters_file)
        from ocplace.methods.no_llm.model import params_sha256

        described["from_scratch"] = read_run_file(self.run_dir)
        described["backbone"]["weights_sha256"] = params_sha256(self.tower.params)
        described["adapters"]["weights_sha256"] = params_sha256(self.policy.grounding.params)
        return described


def load(ctx: LoadContext) -> NoPretrainMethod:
    from ocplace.methods.no_pretrain.model import BACKBONE_DIR
    from ocplace.models.offline_backbone import load_saved_backbone
    from ocplace.models.policy import PlacementPolicy

    adapters_file = trained_run_weights(ctx.run_dir, "tower and adapters", "no_pretrain")
    run_dir = ctx.trained_run
    backbone = load_saved_backbone(run_dir / BACKBONE_DIR)
    policy = PlacementPolicy.from_run(backbone, adapters_file, parser=ctx.parser, **policy_settings(ctx, "no_pretrain"))
    return NoPretrainMethod(
        "no_pretrain", policy, f"offline:{run_dir / BACKBONE_DIR}", adapters_file, run_dir, backbone
    )


SPEC: MethodSpec[Recipe] = MethodSpec(
    "no_pretrain", "Ours w/o CLIP pre-train", load=load, train=train, uses_backbone=False
)
