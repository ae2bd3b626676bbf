"""Table I rows "Ours w/o LLM" (`no_llm`) and "Ours w/o CLIP pre-train" as evaluation methods.

"no_llm" (`models/no_llm.py`, `train/no_llm.py`): no parser; the instruction is one text token, the
top-L visual tokens are the references (L from the scene's level, the one ground-truth input
this ablation is allowed) and an MLP picks each one's relation. Scenes are prepared (crops,
workspace, AABBs) and sampled by the placement policy's own stages, so only the program
(references and relations) differs from Ours.

"no_pretrain" (`models/no_pretrain.py`, `train/no_pretrain.py`): the offline backbone's architecture at
random initialisation, trained with the adapters on the training split; at test time it is
Ours' policy (parser, grounding, sampler) on that tower and those adapters.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ocplace.errors import OcplaceError, TrainingError
from ocplace.eval.api import LoadContext, MethodOutput, MethodSpec, TrainContext
from ocplace.eval.ours import (
    PolicyMethod,
    describe_policy,
    json_default,
    prepare_train_features,
    scene_input,
    trained_run_weights,
)
from ocplace.paths import WEIGHTS_FILE, read_run_file
from ocplace.sim.dataset.records import SceneRecord

# ----------------------------------------------------------------------------- Ours w/o LLM


def train_no_llm(ctx: TrainContext) -> Path:
    """Featurize the training split (shared cache) and its sentences, then train no_llm (idempotent)."""
    from ocplace.models.policy import load_backbone_spec
    from ocplace.train import no_llm

    return no_llm.train_no_llm(
        Path(ctx.dataset_dir),
        load_backbone_spec(ctx.backbone),
        Path(ctx.out_dir),
        dataclasses.replace(ctx.recipe, fraction=ctx.fraction, seed=ctx.seed),
        progress=False,
    )


@dataclasses.dataclass
class NoLlmMethod:
    """A `Method` around a trained no_llm model; `policy` lends its scene preparation and sampler."""

    name: str
    policy: object  # PlacementPolicy: prepare, encode (visual tokens only), sample
    trained: object  # models.no_llm.TrainedNoLlm
    backbone_spec: str
    run_dir: Path

    def run(self, scenes: Sequence[SceneRecord], key) -> list[MethodOutput]:
        prepared: list = []
        for scene in scenes:
            try:
                prepared.append(self.policy.prepare(scene_input(scene)))
            except OcplaceError as error:
                prepared.append(error)
        ready = [i for i, p in enumerate(prepared) if not isinstance(p, OcplaceError)]
        references: dict[int, tuple] = {}
        chunk_size = self.policy.encode_scenes
        for start in range(0, len(ready), chunk_size):
            chunk = ready[start : start + chunk_size]
            references.update(zip(chunk, self.program([prepared[i] for i in chunk], [scenes[i].level for i in chunk])))
        sampled = dict(
            zip(ready, self.policy.sample([prepared[i] for i in ready], [references[i] for i in ready], key))
        )
        return [self._output(prepared[i], references.get(i), sampled.get(i)) for i in range(len(scenes))]

    def program(self, prepared: Sequence, levels: Sequence[str]) -> list[tuple]:
        """Per scene, the chosen references with their predicted relations (`GroundedReference`s)."""
        from ocplace.models.no_llm import REFERENCES_BY_LEVEL, encode_sentences
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
    def _output(prepared, references, sampled) -> MethodOutput:
        failure = next((x for x in (prepared, sampled) if isinstance(x, OcplaceError)), None)
        grounded = tuple(ref.token for ref in references) if references else None
        if failure is not None:
            return MethodOutput(
                mode=None, samples=None, grounded=grounded, failure=f"{type(failure).__name__}: {failure}"
            )
        samples, _, mode = sampled
        return MethodOutput(
            mode=np.asarray(mode, np.float64), samples=np.asarray(samples, np.float64), parsed=None, grounded=grounded
        )

    def describe(self) -> dict:
        model = self.trained.model
        return json.loads(
            json.dumps(
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
                default=json_default,
            )
        )


def load_no_llm(ctx: LoadContext) -> NoLlmMethod:
    from ocplace.models.backbone import PromptConfig
    from ocplace.models.grounding import GroundingModel
    from ocplace.models.no_llm import load_model
    from ocplace.models.placement.sampler import SamplerConfig
    from ocplace.models.policy import PlacementPolicy, load_backbone_spec

    if ctx.run_dir is None:
        raise TrainingError("no_llm needs a run directory; train it first")
    trained = load_model(ctx.run_dir)
    backbone = load_backbone_spec(ctx.backbone)
    if trained.backbone_fingerprint != backbone.fingerprint:
        raise TrainingError(
            f"the no_llm model in {ctx.run_dir} was trained on another backbone (fingerprint "
            f"{trained.backbone_fingerprint[:12]}, {ctx.backbone} is {backbone.fingerprint[:12]})"
        )
    # Grounding and parsing are the model's own; the policy only prepares scenes and samples.
    policy = PlacementPolicy(
        backbone,
        GroundingModel.zero_shot(backbone.dim, backbone.logit_scale),
        PromptConfig(),
        parser=None,
        sampler=SamplerConfig(num_samples=ctx.num_samples),
    )
    return NoLlmMethod("no_llm", policy, trained, ctx.backbone, Path(ctx.run_dir))


# ----------------------------------------------------------------------------- Ours w/o CLIP pre-train


def train_no_pretrain(ctx: TrainContext) -> Path:
    """Train the tower and adapters from random weights (`ctx.backbone` is not used: nothing is pretrained)."""
    from ocplace.train import no_pretrain

    train = dataclasses.replace(ctx.recipe.train, fraction=ctx.fraction, seed=ctx.seed)
    recipe = dataclasses.replace(ctx.recipe, train=train)
    return no_pretrain.train_no_pretrain(Path(ctx.dataset_dir), Path(ctx.out_dir), recipe, progress=False)


@dataclasses.dataclass
class NoPretrainMethod(PolicyMethod):
    run_dir: Path | None = None

    def describe(self) -> dict:
        described = describe_policy(self.policy, self.name, self.backbone_spec, self.adapters_file)
        from ocplace.models.no_llm import params_sha256

        described["from_scratch"] = read_run_file(self.run_dir)
        described["backbone"]["weights_sha256"] = params_sha256(self.policy.backbone.params)
        described["adapters"]["weights_sha256"] = params_sha256(self.policy.grounding.params)
        return described


def load_no_pretrain(ctx: LoadContext) -> NoPretrainMethod:
    from ocplace.models.no_pretrain import BACKBONE_DIR
    from ocplace.models.offline_backbone import load_saved_backbone
    from ocplace.models.placement.sampler import SamplerConfig
    from ocplace.models.policy import PlacementPolicy

    adapters_file = trained_run_weights(ctx.run_dir, "tower and adapters", "no_pretrain")
    run_dir = Path(ctx.run_dir)
    backbone = load_saved_backbone(run_dir / BACKBONE_DIR)
    policy = PlacementPolicy.from_run(
        backbone, adapters_file, parser=ctx.parser, sampler=SamplerConfig(num_samples=ctx.num_samples)
    )
    return NoPretrainMethod("no_pretrain", policy, f"offline:{run_dir / BACKBONE_DIR}", adapters_file, run_dir)


METHODS = (
    MethodSpec("no_llm", "Ours w/o LLM", load=load_no_llm, train=train_no_llm, prepare=prepare_train_features),
    MethodSpec("no_pretrain", "Ours w/o CLIP pre-train", load=load_no_pretrain, train=train_no_pretrain),
)
