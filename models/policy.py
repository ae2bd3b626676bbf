"""The end-to-end placement policy: RGB-D + boxes + instruction -> a placement (the API a robot calls).

    policy = PlacementPolicy.from_run(load_backbone("offline"), "runs/ours")  # or adapters=None: zero-shot
    placement = policy.place(rgb, depth, boxes, "put it to the left of the red bowl.",
                             held_footprint=(0.03, 0.04), key=jax.random.key(0), camera=camera_json)
    placement.mode, placement.mode_px   # table-frame metres (x right, y away), and pixels (u, v)

Stages (each a method, so `perf/policy.py` can time them): `prepare` (check the input, cut the
crops and the workspace image exactly as training did, estimate AABBs from depth when none are
given), `parse`, `encode` (N + 1 crops and L phrases through the frozen backbone), `ground`
(adapters + softmax over the N + 1 tokens), `sample` (the truncated-Gaussian sampler, one
vmapped call for every scene). `place` runs them on one scene and raises typed errors;
`place_many` runs the same stages on many scenes at once (crops encoded in batches, one sampler
call): each scene goes through them as a `SceneProgress`, a stage refuses a scene by raising an
`OcplaceError` (kept on that scene, which the later stages skip), and its `Placement` carries the error and
its `flag` instead of raising.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ocplace.errors import (
    ConfigError,
    GroundingUncertain,
    NoFeasiblePlacement,
    NoObjectBoxes,
    OcplaceError,
    PolicyInputError,
)
from ocplace.models.backbone import Backbone, ClipBackbone, PromptConfig
from ocplace.models.backbone_match import check_trained_on
from ocplace.models.detection import DetectorConfig, detect_boxes, estimate_aabbs
from ocplace.models.grounding import GroundingModel
from ocplace.models.inference_settings import ROBOT_DECISION, Decision
from ocplace.models.parsing import ParsedTuple, Parser
from ocplace.models.placement.sampler import SamplerConfig
from ocplace.models.policy_folder import export_policy, read_policy_folder
from ocplace.models.trained_adapters import TrainedAdapters, load_adapters
from ocplace.sim import metric
from ocplace.sim.camera import DEFAULT_CAMERA
from ocplace.sim.dataset.loader import CROP_SIZE, MAX_BOXES, letterbox
from ocplace.sim.pinhole import PinholeCamera
from ocplace.vocabulary import GATE_THRESHOLD, MAX_PARSED_TUPLES

DEFAULT_THRESHOLD = GATE_THRESHOLD
TABLE_LABEL = "the table"


@dataclasses.dataclass(frozen=True)
class SceneInput:
    """One scene as a robot sees it; see `PlacementPolicy.place` for the fields."""

    rgb: np.ndarray
    depth: np.ndarray
    boxes_or_segmentation: np.ndarray | None
    instruction: str
    held_footprint: Any
    camera: Any = DEFAULT_CAMERA
    object_aabbs: np.ndarray | None = None
    name: str = "scene"


@dataclasses.dataclass(frozen=True)
class PreparedScene:
    """A checked scene with the model's inputs cut out of it."""

    name: str
    instruction: str
    rgb: np.ndarray  # (H, W, 3) uint8
    camera: PinholeCamera
    boxes: np.ndarray  # (N, 4) int32 pixel boxes (u0, v0, u1, v1); box order = visual token order
    aabbs: np.ndarray  # (N, 2, 2) table-frame x-y AABB per box
    crops: np.ndarray  # (N, S, S, 3) uint8, as `sim.dataset.loader.example_from_record` cuts them
    workspace: np.ndarray  # (S, S, 3) uint8 letterboxed image: visual token N, the table
    half_extents: np.ndarray  # (2,) held object's footprint half-extents, metres
    flags: tuple[str, ...]  # "boxes_detected", "aabbs_estimated"


@dataclasses.dataclass(frozen=True)
class Tokens:
    """Backbone features of a batch of scenes, padded."""

    visual: np.ndarray  # (B, T, D): crops in box order, the workspace at index N, zeros after
    visual_mask: np.ndarray  # (B, T) bool
    text: np.ndarray  # (B, L, D) one token per parsed tuple
    text_mask: np.ndarray  # (B, L) bool


@dataclasses.dataclass(frozen=True)
class GroundedReference:
    phrase: str
    relation: str  # canonical
    token: int  # index among the N + 1 visual tokens; N = the table
    probability: float  # P of that token
    probabilities: np.ndarray  # (N + 1,) P over the visual tokens
    box: np.ndarray | None  # (4,) pixel box of the grounded object; None: the table
    aabb: np.ndarray | None  # (2, 2) its table-frame AABB; None: the table

    @property
    def is_table(self) -> bool:
        return self.box is None


Sampled = tuple[np.ndarray, np.ndarray, np.ndarray]  # (samples (S, 2), heatmap (nx, ny), mode (2,))


@dataclasses.dataclass
class SceneProgress:
    """One scene on its way through the policy's stages: what each made, until one refused it (`error`).

    A stage refuses a scene by raising an `OcplaceError`; `attempt` keeps it here, so that one scene's refusal
    never stops the others of a batch (`place_many`), and `place` raises it."""

    scene: SceneInput
    prepared: PreparedScene | None = None
    parsed: tuple[ParsedTuple, ...] | None = None
    references: tuple[GroundedReference, ...] | None = None
    decision: str = "argmax"  # how `references` were chosen: "argmax", "joint" or "joint_fallback"
    sampled: Sampled | None = None
    error: OcplaceError | None = None

    @property
    def ok(self) -> bool:
        return self.error is None

    def parsed_scene(self) -> tuple[PreparedScene, tuple[ParsedTuple, ...]]:
        """What the prepare and parse stages made, for the stages after them (which see only scenes both passed)."""
        assert self.prepared is not None and self.parsed is not None, "a stage after parsing saw an unparsed scene"
        return self.prepared, self.parsed

    def attempt(self, stage: Callable[..., Any], *args: Any) -> Any:
        """`stage(*args)`, or None with its OcplaceError kept as this scene's `error`."""
        try:
            return stage(*args)
        except OcplaceError as error:
            self.error = error
            return None


@dataclasses.dataclass(frozen=True)
class Placement:
    """What the policy did in one scene. `error` is set (and `mode` None) when it did not place."""

    name: str
    instruction: str
    parsed: tuple[ParsedTuple, ...]
    references: tuple[GroundedReference, ...]
    boxes: np.ndarray  # (N, 4) pixel boxes used
    aabbs: np.ndarray  # (N, 2, 2) table-frame AABBs used for collisions
    samples: np.ndarray | None  # (num_samples, 2) table-frame metres
    samples_px: np.ndarray | None  # (num_samples, 2) pixels (u, v)
    mode: np.ndarray | None  # (2,) the most probable placement, table-frame metres
    mode_px: np.ndarray | None  # (2,) pixels
    heatmap: np.ndarray | None  # (nx, ny) density per m^2 on `grid`
    grid: metric.Grid
    flags: tuple[str, ...]
    error: OcplaceError | None = None
    # How the references' tokens were chosen (`Decision`): "argmax", "joint", or "joint_fallback" (no
    # consistent feasible assignment among the candidates: the argmax one, flagged `no_feasible_assignment`).
    decision: str = "argmax"

    @property
    def ok(self) -> bool:
        return self.error is None

    @property
    def assignment_probability(self) -> float | None:
        """The joint probability of the chosen tokens (the product over the references); None without any."""
        return float(np.prod([ref.probability for ref in self.references])) if self.references else None

    @property
    def failure(self) -> str | None:
        return None if self.error is None else f"{type(self.error).__name__}: {self.error}"

    @property
    def pairs(self) -> tuple[tuple[str, str], ...]:
        return tuple((t.reference, t.relation) for t in self.parsed)

    @property
    def tokens(self) -> tuple[int, ...]:
        return tuple(r.token for r in self.references)

    def summary(self) -> str:
        lines = [
            f"{self.name}: {self.instruction!r}",
            "  parse: " + ("; ".join(f"<{ref}, {rel}>" for ref, rel in self.pairs) or "-"),
        ]
        for ref in self.references:
            where = TABLE_LABEL if ref.is_table or ref.box is None else f"box {ref.token} {ref.box.tolist()}"
            lines.append(f"  {ref.phrase!r} -> {where} (p={ref.probability:.3f}), relation {ref.relation}")
        if self.mode is not None and self.mode_px is not None and self.samples is not None:  # set together
            lines.append(
                f"  mode: ({self.mode[0]:+.4f}, {self.mode[1]:+.4f}) m = pixel "
                f"({self.mode_px[0]:.1f}, {self.mode_px[1]:.1f}); {len(self.samples)} samples"
            )
        if self.decision != "argmax" and self.references:
            lines.append(f"  decision: {self.decision} (joint P={self.assignment_probability:.3f})")
        if self.flags:
            lines.append(f"  flags: {', '.join(self.flags)}")
        if self.error is not None:
            lines.append(f"  not placed: {self.failure}")
        return "\n".join(lines)


@dataclasses.dataclass(frozen=True)
class PlacementPolicy:
    """Parser + frozen backbone + grounding adapters + sampler."""

    backbone: Backbone
    grounding: GroundingModel
    prompt: PromptConfig
    parser: Parser | None  # None: a policy that is never asked to parse (w/o LLM grounds the sentence itself)
    sampler: SamplerConfig = SamplerConfig()
    threshold: float = DEFAULT_THRESHOLD  # least max-probability a reference needs to be placed against
    detector: DetectorConfig = DetectorConfig()
    crop_size: int = CROP_SIZE
    min_boxes: int = MAX_BOXES  # tokens and collision boxes are padded to at least this: one compiled shape
    max_tuples: int = MAX_PARSED_TUPLES
    encode_scenes: int = 32  # scenes whose crops are encoded together in `place_many`
    # The joint, feasibility-aware choice (rule J's default), or the paper's argmax per reference (`Decision()`).
    decision: Decision = ROBOT_DECISION

    def __post_init__(self) -> None:
        problems = self.decision.problems(self.max_tuples)
        if problems:
            raise ConfigError("invalid policy settings: " + "; ".join(problems))

    @classmethod
    def from_run(cls, backbone: Backbone, adapters=None, parser: Parser | str = "offline", **kwargs) -> PlacementPolicy:
        """A policy from trained adapters (a run directory, an adapters file, or `TrainedAdapters` already
        loaded; None: zero-shot grounding).

        Raises TrainingError when the adapters were trained on another backbone's features.
        """
        from ocplace.models.parsing import make_parser

        if isinstance(parser, str):
            parser = make_parser(parser)
        if adapters is None:
            return cls(
                backbone, GroundingModel.zero_shot(backbone.dim, backbone.logit_scale), PromptConfig(), parser, **kwargs
            )
        trained = adapters if isinstance(adapters, TrainedAdapters) else load_adapters(adapters)
        check_trained_on(backbone, trained.backbone_fingerprint, f"the adapters in {trained.source} were")
        return cls(backbone, trained.model, trained.prompt, parser, **kwargs)

    @classmethod
    def from_pretrained(cls, directory, parser: Parser | str | None = None, **kwargs) -> PlacementPolicy:
        """The policy a policy folder holds (`ocplace export`; `out/demo/policy` after `make demo`), with no cache:
        backbone, adapters and settings from its `config.json` and `model.safetensors`. `parser`: None for the
        folder's own; `kwargs` override policy fields (`sampler`, `threshold`, ...). PolicyFolderError when the
        folder is missing, tampered or of another format."""
        checkpoint = kwargs.pop("checkpoint", None)  # where a CLIP folder's checkpoint is now, if it moved
        return cls(**(read_policy_folder(directory, parser, checkpoint=checkpoint) | kwargs))

    def save_pretrained(self, directory, parser: str | None = None):
        """This policy as a policy folder `directory` (what `from_pretrained` loads), with its model card; `parser`:
        the parser spec to record (default: this policy's parser's name). Returns the folder."""
        from ocplace.models.policy_card import card_text

        kind = "clip" if isinstance(self.backbone, ClipBackbone) else "offline"
        source = {"backbone": f"{kind}:{getattr(self.backbone, 'source', '')}"}
        recorded = parser or str(getattr(self.parser, "name", "offline"))
        return export_policy(self, directory, parser=recorded, card=card_text(Path(directory), source))

    # ------------------------------------------------------------------ public calls

    def place(
        self,
        rgb,
        depth,
        boxes_or_segmentation,
        instruction: str,
        held_footprint,
        key,
        camera=DEFAULT_CAMERA,
        object_aabbs=None,
    ) -> Placement:
        """Places the held object in one scene; raises a typed `OcplaceError` instead of placing blindly.

        Args:
          rgb: uint8 `(H, W, 3)`.
          depth: `(H, W)` planar depth, float metres (an integer image is read as millimetres).
          boxes_or_segmentation: int `(N, 4)` pixel boxes (u0, v0, u1, v1) from any detector, in the
            order of the visual tokens; or an `(H, W)` segmentation image (0 = background, one id per
            object; ids with >= 200 pixels get a box); or None: boxes from `models.detection`.
          instruction: free text, e.g. "put it behind the red bowl and to the left of the mug."
          held_footprint: `(hx, hy)` half-extents of the held object's x-y footprint, metres.
          key: a `jax.random` key for the samples.
          camera: a `PinholeCamera`, a `sim.camera.Camera`, a dict like a dataset scene.json's `camera`
            (intrinsics, world_from_camera, width, height) or a path to such a JSON file.
          object_aabbs: `(N, 2, 2)` table-frame x-y AABBs `[[xmin, ymin], [xmax, ymax]]` per box; None:
            estimated from depth.

        Raises:
          PolicyInputError (mismatched sizes, bad boxes or camera), NoObjectBoxes, ParseError,
          GroundingUncertain, InvalidPlacementProblem, NoFeasiblePlacement.
        """
        scene = SceneInput(rgb, depth, boxes_or_segmentation, instruction, held_footprint, camera, object_aabbs)
        [placement] = self.place_many([scene], key)
        if placement.error is not None:
            raise placement.error
        return placement

    def place_many(self, scenes: Sequence[SceneInput], key, progress: bool = False) -> list[Placement]:
        """`place` on many scenes: crops encoded in batches, one vmapped sampler call. Never raises an
        `OcplaceError` for one scene: that scene's Placement carries it (`error`, `failure`)."""
        runs = [SceneProgress(scene) for scene in scenes]
        for run in runs:
            run.prepared = run.attempt(self.prepare, run.scene)
            if run.ok:
                run.parsed = run.attempt(self.parse, run.scene.instruction)
            if run.ok:
                run.attempt(_check_boxes_for, run.prepared, run.parsed)
        ready = [run for run in runs if run.ok]
        chunks = [ready[start : start + self.encode_scenes] for start in range(0, len(ready), self.encode_scenes)]
        for chunk in _progress(chunks, progress, "encode"):
            tokens = self.encode([run.prepared for run in chunk], [run.parsed for run in chunk])
            self.decide_many(chunk, self.ground(tokens))
            for run in chunk:
                run.attempt(self.check_confidence, run.prepared, run.references)
        self.sample([run for run in ready if run.ok], key)
        return [self._assemble(run) for run in runs]

    # ------------------------------------------------------------------ stages

    def prepare(self, scene: SceneInput) -> PreparedScene:
        """Checks one scene and cuts its crops and workspace image (224 px, as in training)."""
        from ocplace.sim.boxes import boxes_from_segmentation, square_crop

        rgb, depth, camera, half_extents = check_scene(scene)
        flags, segmentation, object_ids = [], None, None
        given = scene.boxes_or_segmentation
        if given is None:
            boxes = detect_boxes(depth, camera, self.detector)
            flags.append("boxes_detected")
        elif _is_segmentation(given, rgb):
            segmentation = np.asarray(given)
            found = boxes_from_segmentation(segmentation)
            boxes, object_ids = found.boxes, found.object_ids
        else:
            boxes = _check_boxes(given, rgb.shape)
        if scene.object_aabbs is None:
            aabbs = estimate_aabbs(depth, camera, boxes, segmentation, object_ids, self.detector)
            flags.append("aabbs_estimated")
        else:
            aabbs = _check_aabbs(scene.object_aabbs, len(boxes))
        crops = (
            np.stack([square_crop(rgb, box, size=self.crop_size) for box in boxes])
            if len(boxes)
            else np.zeros((0, self.crop_size, self.crop_size, 3), np.uint8)
        )
        return PreparedScene(
            scene.name,
            scene.instruction,
            rgb,
            camera,
            boxes,
            aabbs,
            crops,
            letterbox(rgb, self.crop_size),
            half_extents,
            tuple(flags),
        )

    def parse(self, instruction: str) -> tuple[ParsedTuple, ...]:
        from ocplace.errors import InvalidPlacementProblem

        if self.parser is None:
            raise TypeError("this policy was built without a parser (w/o LLM's): it cannot parse instructions")
        parsed = tuple(self.parser.parse(instruction))
        if not 1 <= len(parsed) <= self.max_tuples:
            raise InvalidPlacementProblem(
                f"the instruction {instruction!r} gave {len(parsed)} tuples; the policy "
                f"places against 1 to {self.max_tuples}"
            )
        return parsed

    def encode(self, scenes: Sequence[PreparedScene], parses: Sequence[Sequence[ParsedTuple]]) -> Tokens:
        """Backbone features of every crop, workspace and phrase of `scenes`, in two backbone calls."""
        from ocplace.models.features import encode_images_any_size

        images = [crop for scene in scenes for crop in scene.crops] + [scene.workspace for scene in scenes]
        image_features = encode_images_any_size(self.backbone, images)
        texts = [self.prompt.text_for(t.reference) for parsed in parses for t in parsed]
        text_features = self.backbone.encode_texts(texts)
        count, dim = len(scenes), self.backbone.dim
        num_tokens = max([self.min_boxes] + [len(scene.boxes) for scene in scenes]) + 1
        tokens = Tokens(
            np.zeros((count, num_tokens, dim), np.float32),
            np.zeros((count, num_tokens), bool),
            np.zeros((count, self.max_tuples, dim), np.float32),
            np.zeros((count, self.max_tuples), bool),
        )
        crop_row, text_row, workspace_row = 0, 0, len(images) - count
        for i, (scene, parsed) in enumerate(zip(scenes, parses)):
            n, num_texts = len(scene.boxes), len(parsed)
            tokens.visual[i, :n] = image_features[crop_row : crop_row + n]
            tokens.visual[i, n] = image_features[workspace_row + i]
            tokens.visual_mask[i, : n + 1] = True
            tokens.text[i, :num_texts] = text_features[text_row : text_row + num_texts]
            tokens.text_mask[i, :num_texts] = True
            crop_row, text_row = crop_row + n, text_row + num_texts
        return tokens

    def ground(self, tokens: Tokens) -> np.ndarray:
        """`(B, L, T)` P over the visual tokens per tuple (rows past a scene's tuples are padding)."""
        return self.grounding.probabilities(tokens.text, tokens.visual, tokens.visual_mask)

    def decide_many(self, runs: Sequence[SceneProgress], probabilities: np.ndarray) -> None:
        """Sets each run's `references` (and `decision`) from its row of `(B, L, T)` probabilities, as
        `self.decision` says: every reference at its argmax, or the joint choice of all of a batch's scenes in one
        jitted call (`models/joint_grounding.py`)."""
        choice = None
        if self.decision.mode == "joint" and runs:
            import jax

            from ocplace.models.joint_grounding import choose_assignments

            problem = self._joint_problem(runs, probabilities)
            choice = jax.device_get(choose_assignments(problem, self.decision.top_k, self.sampler.grid))
        for row, run in enumerate(runs):
            prepared, parsed = run.parsed_scene()
            tokens = None
            if choice is not None:
                tokens = [int(token) for token in choice.tokens[row, : len(parsed)]]
                run.decision = "joint" if choice.found[row] else "joint_fallback"
            run.references = self.decide(prepared, parsed, probabilities[row], tokens)

    def _joint_problem(self, runs: Sequence[SceneProgress], probabilities: np.ndarray):
        """The `JointProblem` of `runs` (prepared and parsed), padded to whole steps of scenes."""
        from ocplace.models.joint_grounding import SCENES_PER_STEP, JointProblem
        from ocplace.sim import relations

        parsed_scenes = [run.parsed_scene() for run in runs]
        num_tuples = max(len(parsed) for _, parsed in parsed_scenes)
        num_tokens = probabilities.shape[-1]
        num_boxes = max([self.min_boxes] + [len(prepared.boxes) for prepared, _ in parsed_scenes])
        scenes = []
        for row, (prepared, parsed) in enumerate(parsed_scenes):
            count = len(prepared.boxes)
            token_boxes = np.zeros((num_tokens, 2, 2), np.float32)
            token_boxes[:count] = prepared.aabbs
            names = [item.reference for item in parsed] + [None] * (num_tuples - len(parsed))
            relation = [relations.relation_index(item.relation) for item in parsed] + [0] * (num_tuples - len(parsed))
            scenes.append(
                JointProblem(
                    probabilities=np.asarray(probabilities[row, :num_tuples], np.float32),
                    tuple_mask=np.arange(num_tuples) < len(parsed),
                    relation=np.asarray(relation, np.int32),
                    same_name=np.array([[a == b for b in names] for a in names], bool),
                    num_boxes=np.int32(count),
                    token_boxes=token_boxes,
                    boxes=np.concatenate([token_boxes[:count], np.zeros((num_boxes - count, 2, 2), np.float32)]),
                    box_mask=np.arange(num_boxes) < count,
                    half_extents=np.asarray(prepared.half_extents, np.float32),
                )
            )
        scenes += scenes[:1] * (-len(scenes) % SCENES_PER_STEP)  # whole steps: few compiled shapes
        return JointProblem(*(np.stack(field) for field in zip(*scenes)))

    def decide(
        self,
        scene: PreparedScene,
        parsed: Sequence[ParsedTuple],
        probabilities: np.ndarray,
        tokens: Sequence[int] | None = None,
    ) -> tuple[GroundedReference, ...]:
        """The grounded reference per tuple, from `(L, T)` probabilities: at `tokens` when given, else at each
        tuple's argmax."""
        num_tokens = len(scene.boxes) + 1
        references = []
        for k, item in enumerate(parsed):
            row = np.asarray(probabilities[k, :num_tokens], np.float64)
            token = int(np.argmax(row)) if tokens is None else int(tokens[k])
            is_table = token == len(scene.boxes)
            references.append(
                GroundedReference(
                    item.reference,
                    item.relation,
                    token,
                    float(row[token]),
                    row,
                    None if is_table else scene.boxes[token],
                    None if is_table else scene.aabbs[token],
                )
            )
        return tuple(references)

    def check_confidence(self, scene: PreparedScene, references: Sequence[GroundedReference]) -> None:
        """Raises GroundingUncertain for the first reference whose best token is below the threshold (or NaN)."""
        for ref in references:
            if not ref.probability >= self.threshold:  # written so that NaN (every comparison False) refuses
                best = np.argsort(-ref.probabilities, kind="stable")[:3]
                raise GroundingUncertain(
                    ref.phrase,
                    [(_token_label(scene, int(t)), float(ref.probabilities[t])) for t in best],
                    self.threshold,
                )

    def problem(self, scene: PreparedScene, references: Sequence[GroundedReference]) -> metric.PlacementProblem:
        tuples = [metric.GroundedTuple(ref.relation, ref.aabb) for ref in references]
        return metric.encode_problem(
            tuples,
            scene.aabbs,
            scene.half_extents,
            max_tuples=self.max_tuples,
            max_boxes=max(self.min_boxes, len(scene.aabbs)),
        )

    def sample(self, runs: Sequence[SceneProgress], key) -> None:
        """One sampler call for the prepared and grounded scenes of `runs`: each gets `sampled` or its `error`."""
        import jax

        from ocplace.models.placement import explain_empty, sample_placements

        problems = [(run, run.attempt(self.problem, run.prepared, run.references)) for run in runs]
        valid = [(run, problem) for run, problem in problems if run.ok]
        if not valid:
            return
        batch = [problem for _, problem in valid]
        batch += batch[:1] * (_padded_count(len(batch), self.sampler.scenes_per_step) - len(batch))
        result = jax.device_get(sample_placements(key, metric.stack_problems(batch), self.sampler))
        for row, (run, problem) in enumerate(valid):
            if result.empty[row]:
                assert run.prepared is not None, "a scene is sampled once prepared (w/o LLM's too, which parses none)"
                run.error = NoFeasiblePlacement(run.prepared.name, explain_empty(problem, self.sampler.grid))
            else:
                run.sampled = (result.samples[row], result.heatmap[row], result.mode[row])

    # ------------------------------------------------------------------ assembly

    def _assemble(self, run: SceneProgress) -> Placement:
        prepared, error = run.prepared, run.error
        boxes = prepared.boxes if prepared is not None else np.zeros((0, 4), np.int32)
        flags = list(prepared.flags) if prepared is not None else []
        if prepared is not None and not len(boxes):
            flags.append("no_boxes")
        if run.decision == "joint_fallback":
            flags.append("no_feasible_assignment")
        if error is not None:
            flags.append(error.flag)
        samples = mode = heatmap = samples_px = mode_px = None
        if error is None and run.sampled is not None and prepared is not None:
            samples, heatmap, mode = (np.asarray(x) for x in run.sampled)
            samples_px, mode_px = prepared.camera.table_to_pixel(samples), prepared.camera.table_to_pixel(mode)
        return Placement(
            name=run.scene.name,
            instruction=run.scene.instruction,
            parsed=run.parsed or (),
            references=run.references or (),
            boxes=boxes,
            aabbs=prepared.aabbs if prepared is not None else np.zeros((0, 2, 2)),
            samples=samples,
            samples_px=samples_px,
            mode=mode,
            mode_px=mode_px,
            heatmap=heatmap,
            grid=self.sampler.grid,
            flags=tuple(flags),
            error=error,
            decision=run.decision,
        )


def _padded_count(count: int, step: int) -> int:
    """One scene stays one (a robot's latency); batches round up to whole sampler steps, so a batched
    evaluation compiles the sampler for few shapes."""
    return count if count == 1 else -(-count // step) * step


def _progress(items, enabled: bool, desc: str):
    if not enabled:
        return items
    from ocplace.runtime.progress import progress_bar

    return progress_bar(items, desc=desc, unit="chunk")


def _check_boxes_for(scene: PreparedScene, parsed: Sequence[ParsedTuple]) -> None:
    """An image without boxes can still take a table-only instruction; not one about an object."""
    objects = [t.reference for t in parsed if not t.is_table]
    if not len(scene.boxes) and objects:
        raise NoObjectBoxes(
            f"scene {scene.name} has no object box, but the instruction refers to {objects[0]!r}; "
            "pass boxes from a detector, a segmentation image, or check the depth image "
            "(the depth detector found nothing above the table)"
        )


def _token_label(scene: PreparedScene, token: int) -> str:
    return TABLE_LABEL if token == len(scene.boxes) else f"box {token} {scene.boxes[token].tolist()}"


def check_scene(scene: SceneInput) -> tuple[np.ndarray, np.ndarray, PinholeCamera, np.ndarray]:
    """(rgb, depth, camera, held half-extents) of `scene`, checked: everything about a scene that can be
    refused without a model (sizes that disagree, a bad camera or footprint), so that a caller can refuse it
    before a backbone loads. PolicyInputError names what is wrong."""
    rgb, depth = _check_images(scene.rgb, scene.depth)
    camera = PinholeCamera.from_any(scene.camera)
    if (camera.width, camera.height) != (rgb.shape[1], rgb.shape[0]):
        raise PolicyInputError(
            f"the camera is {camera.width}x{camera.height} but the images are "
            f"{rgb.shape[1]}x{rgb.shape[0]}; pass the intrinsics of this image"
        )
    given = scene.boxes_or_segmentation
    is_boxes = given is not None and ((np.ndim(given) == 2 and np.shape(given)[1] == 4) or np.size(given) == 0)
    if given is not None and not (_is_segmentation(given, rgb) or is_boxes):
        raise PolicyInputError(
            f"the segmentation (boxes_or_segmentation) has shape {np.shape(given)}: pass a segmentation image "
            f"of the image's size {rgb.shape[1]}x{rgb.shape[0]} (shape {rgb.shape[:2]}), or (N, 4) pixel boxes"
        )
    half_extents = np.asarray(scene.held_footprint, np.float64).reshape(-1)
    if half_extents.shape != (2,) or not np.all(np.isfinite(half_extents) & (half_extents >= 0)):
        raise PolicyInputError(
            f"held_footprint must be two half-extents (hx, hy) >= 0 in metres, got {scene.held_footprint!r}"
        )
    return rgb, depth, camera, half_extents


def _is_segmentation(given, rgb: np.ndarray) -> bool:
    return np.ndim(given) == 2 and np.shape(given) == rgb.shape[:2] and np.shape(given)[1] != 4


def _check_images(rgb, depth) -> tuple[np.ndarray, np.ndarray]:
    rgb, depth = np.asarray(rgb), np.asarray(depth)
    if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[-1] != 3:
        raise PolicyInputError(f"rgb must be a uint8 (H, W, 3) image, got {rgb.dtype} {rgb.shape}")
    depth = check_depth(depth)
    if depth.shape != rgb.shape[:2]:
        raise PolicyInputError(
            f"rgb is {rgb.shape[1]}x{rgb.shape[0]} but depth is {depth.shape[1]}x{depth.shape[0]}; "
            "register the depth image to the colour image first"
        )
    return np.ascontiguousarray(rgb), depth


def check_depth(depth) -> np.ndarray:
    """`(H, W)` float32 metres from a depth image of numbers (integers are millimetres, as PNGs store them)."""
    depth = np.asarray(depth)
    if not (np.issubdtype(depth.dtype, np.integer) or np.issubdtype(depth.dtype, np.floating)):
        raise PolicyInputError(
            f"depth must hold numbers (float metres or integer millimetres), got dtype {depth.dtype}"
        )
    if depth.ndim != 2:
        raise PolicyInputError(f"depth must be an (H, W) image, got shape {depth.shape}")
    if np.issubdtype(depth.dtype, np.integer):
        return depth.astype(np.float32) / 1000.0
    return depth.astype(np.float32)


def _check_boxes(boxes, image_shape) -> np.ndarray:
    boxes = np.asarray(boxes)
    if boxes.size == 0:
        return np.zeros((0, 4), np.int32)
    if not np.all(np.isfinite(boxes)):
        raise PolicyInputError("boxes must be finite (u0, v0, u1, v1) pixel coordinates")
    boxes = np.round(boxes).astype(np.int32).reshape(-1, 4)
    height, width = image_shape[:2]
    bad = (
        (boxes[:, 0] >= boxes[:, 2])
        | (boxes[:, 1] >= boxes[:, 3])
        | (boxes[:, 0] < 0)
        | (boxes[:, 1] < 0)
        | (boxes[:, 2] > width)
        | (boxes[:, 3] > height)
    )
    if bad.any():
        raise PolicyInputError(
            f"box {int(np.flatnonzero(bad)[0])} {boxes[bad][0].tolist()} is empty or leaves the "
            f"{width}x{height} image; boxes are (u0, v0, u1, v1) pixel edges, u0 < u1 <= width"
        )
    return boxes


def _check_aabbs(aabbs, count: int) -> np.ndarray:
    aabbs = np.asarray(aabbs, np.float64)
    if aabbs.size == 0 and count == 0:
        return np.zeros((0, 2, 2))
    if aabbs.shape != (count, 2, 2) or not np.all(np.isfinite(aabbs)) or np.any(aabbs[:, 0] > aabbs[:, 1]):
        raise PolicyInputError(
            f"object_aabbs must be ({count}, 2, 2) finite [[xmin, ymin], [xmax, ymax]] boxes, one "
            f"per pixel box, got shape {aabbs.shape}"
        )
    return aabbs
