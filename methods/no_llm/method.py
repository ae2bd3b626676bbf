"""Table I row "Ours w/o LLM" (`methods/no_llm/model.py`, `methods/no_llm/train.py`).

No parser: the instruction is one text token, the top-L visual tokens are the references (L from the
scene's level, the one ground-truth input this ablation is allowed) and an MLP picks each one's
relation. Scenes are prepared (crops, workspace, AABBs) and sampled by the placement policy's own
stages, so only the program (references and relations) differs from Ours.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ocplace import serial
from ocplace.eval.api import MethodOutput
from ocplace.methods.contract import LoadContext, MethodSpec, TrainContext
from ocplace.methods.no_llm.recipe import NoLlmRecipe as Recipe
from ocplace.methods.policy_method import prepare_train_features, scene_input
from ocplace.paths import WEIGHTS_FILE
from ocplace.sim.dataset.records import SceneRecord

if TYPE_CHECKING:
    import jax

    from ocplace.methods.no_llm.model import TrainedNoLlm
    from ocplace.models.policy import GroundedReference, PlacementPolicy, PreparedScene, SceneProgress


def train(ctx: TrainContext[Recipe]) -> Path:
    """Featurize the training split (shared cache) and its sentences, then train no_llm (idempotent)."""
    from ocplace.methods.no_llm import train as no_llm
    from ocplace.models.backbone import load_backbone

    return no_llm.train_no_llm(
        Path(ctx.dataset_dir),
        load_backbone(ctx.backbone),
        Path(ctx.out_dir),
        ctx.recipe,
        ctx.seed,
        ctx.fraction,
        progress=True,
    )


@dataclasses.dataclass
class NoLlmMethod:
    """A `Method` around a trained no_llm model; `policy` lends its scene preparation and sampler."""

    name: str
    policy: PlacementPolicy  # lends prepare, encode (visual tokens only) and sample
    trained: TrainedNoLlm
    backbone_spec: str
    run_dir: Path

    def run(self, scenes: Sequence[SceneRecord], key: jax.Array) -> list[MethodOutput]:
        from ocplace.models.policy import SceneProgress

        runs = [SceneProgress(scene_input(scene)) for scene in scenes]
        for run in runs:
            run.prepared = run.attempt(self.policy.prepare, run.scene)
        ready = [(run, run.prepared, scene.level) for run, scene in zip(runs, scenes) if run.prepared is not None]
        for start in range(0, len(ready), self.policy.encode_scenes):
            chunk = ready[start : start + self.policy.encode_scenes]
            programs = self.program([prepared for _, prepared, _ in chunk], [level for _, _, level in chunk])
            for (run, _, _), references in zip(chunk, programs):
                run.references = references
        self.policy.sample([run for run, _, _ in ready], key)
        return [self._output(run) for run in runs]

    def program(self, prepared: Sequence[PreparedScene], levels: Sequence[str]) -> list[tuple[GroundedReference, ...]]:
        """Per scene, the chosen references with their predicted relations (`GroundedReference`s)."""
        from ocplace.methods.no_llm.model import REFERENCES_BY_LEVEL, encode_sentences
        from ocplace.models.policy import GroundedReference
        from ocplace.sim.relations import RELATION_NAMES

        model = self.trained.model
        tokens = self.policy.encode(prepared, [()] * len(prepared))
        sentences = encode_sentences(self.policy.backbone, model.config, [scene.instruction for scene in prepared])
        prediction = model.predict(
            tokens.visual, tokens.visual_mask, sentences, np.array([REFERENCES_BY_LEVEL[level] for level in levels])
        )
        programs = []
        for row, scene in enumerate(prepared):
            num_boxes = len(scene.boxes)
            probabilities = prediction.token_probabilities[row, : num_boxes + 1].astype(np.float64)
            chosen = []
            for slot in np.flatnonzero(prediction.reference_mask[row]):
                token = int(prediction.references[row, slot])
                is_table = token == num_boxes
                chosen.append(
                    GroundedReference(
                        "",
                        RELATION_NAMES[int(prediction.relations[row, slot])],
                        token,
                        float(probabilities[token]),
                        probabilities,
                        None if is_table else scene.boxes[token],
                        None if is_table else scene.aabbs[token],
                    )
                )
            programs.append(tuple(chosen))
        return programs

    @staticmethod
    def _output(run: SceneProgress) -> MethodOutput:
        grounded = tuple(ref.token for ref in run.references) if run.references else None
        if run.error is not None:
            return MethodOutput(
                mode=None, samples=None, grounded=grounded, failure=f"{type(run.error).__name__}: {run.error}"
            )
        assert run.sampled is not None, "every prepared scene is sampled"
        samples, _, mode = run.sampled
        return MethodOutput(
            mode=np.asarray(mode, np.float64), samples=np.asarray(samples, np.float64), parsed=None, grounded=grounded
        )

    def describe(self) -> dict[str, Any]:
        model = self.trained.model
        described: dict[str, Any] = serial.to_dict(
            {
                "method": self.name,
                "backbone": {"spec": self.backbone_spec, "fingerprint": self.policy.backbone.fingerprint},
                "model": {
                    "path": str(Path(self.run_dir) / WEIGHTS_FILE),
                    "weights_sha256": self.trained.sha256,
                    "config": dataclasses.asdict(model.config),
                    "logit_scale": float(model.logit_scale),
                    "train_config": self.trained.train_config,
                    "seed": self.trained.train_config["seed"],
                },
                "references": "top-L visual tokens by adapted similarity to the sentence; L from meta['level'] "
                "(table, 1obj: 1; 2obj: 2)",
                "sampler": dataclasses.asdict(self.policy.sampler),
                "policy": {
                    "crop_size": self.policy.crop_size,
                    "min_boxes": self.policy.min_boxes,
                    "boxes": "dataset (from segmentation)",
                    "aabbs": "dataset (simulator AABBs of boxed objects)",
                },
            },
        )
        return described


def load(ctx: LoadContext) -> NoLlmMethod:
    from ocplace.methods.no_llm.model import load_model
    from ocplace.models.backbone import PromptConfig, load_backbone
    from ocplace.models.backbone_match import check_trained_on
    from ocplace.models.grounding import GroundingModel
    from ocplace.models.placement.sampler import SamplerConfig
    from ocplace.models.policy import PlacementPolicy
    from ocplace.models.shared_features import SharedFeatures

    trained = load_model(ctx.trained_run)
    backbone = load_backbone(ctx.backbone)
    check_trained_on(backbone, trained.backbone_fingerprint, f"the no_llm model in {ctx.run_dir} was")
    # Grounding and parsing are the model's own; the policy only prepares scenes and samples. Its backbone
    # reads the test features Ours' evaluations encoded in the same batches (models/shared_features.py).
    policy = PlacementPolicy(
        SharedFeatures(backbone),
        GroundingModel.zero_shot(backbone.dim, backbone.logit_scale),
        PromptConfig(),
        parser=None,
        sampler=SamplerConfig(num_samples=ctx.num_samples),
    )
    return NoLlmMethod("no_llm", policy, trained, ctx.backbone, ctx.trained_run)


SPEC: MethodSpec[Recipe] = MethodSpec(
    "no_llm", "Ours w/o LLM", load=load, train=train, prepare=prepare_train_features, shares_test_features=True
)
