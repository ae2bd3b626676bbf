"""Scoring methods on the benchmark's test subsets (paper Table I protocol).

A registered method (`eval/api.py`) is run on every scene of a test subset, in chunks; the harness
scores what it returns against the ground truth it never showed the method:

- success of the mode: `sim.metric.placement_success` at `MethodOutput.mode` on `record.problem()`;
- mean success over samples: the same metric averaged over `MethodOutput.samples`;
- physical success (first K scenes of a subset): metric success AND `sim.physical.physical_check`;
- parse and grounding correctness, from which each failed scene is attributed to a stage.

A failure (`MethodOutput.failure`, an exception, or malformed output) scores 0 everywhere and is
listed with its message. Randomness: one jax.random key per (seed, method name, subset), one key per
chunk folded from it; a chunk whose `run` raises is re-run scene by scene with keys folded from the
chunk key, so a failing scene does not sink its neighbours and the outcome stays a function of the
settings.
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import time
import zlib
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from ocplace import serial
from ocplace.errors import POLICY_ERRORS, EvaluationError, PolicyRaised
from ocplace.eval.api import Method, MethodOutput
from ocplace.models.inference_settings import InferenceSettings
from ocplace.sim.boxes import Boxes
from ocplace.sim.dataset.records import SceneRecord
from ocplace.vocabulary import LEVELS, MAX_SAMPLES, TEST_SUBSETS, subsets_problem

if TYPE_CHECKING:
    import jax

    from ocplace.sim.mujoco_backend import MujocoScenes

STAGES = ("failure", "parse", "grounding", "sampling", "placement")
# The per-subset columns pooled from levels besides Overall: each level alone, and the object-referenced
# scenes (a table-only scene is solved by any object-centric method; these are the hard part).
LEVEL_GROUPS = {level: (level,) for level in LEVELS} | {"objects": ("1obj", "2obj")}
DEFAULT_PHYSICAL_SCENES = 50


@dataclasses.dataclass(frozen=True)
class EvalSettings:
    """Everything that decides an evaluation's outcome besides the methods' own runs."""

    backbone: str = "offline"
    experiment: str = "default"  # the experiment's name, recorded; the methods' runs carry their recipes
    parser: str = "offline"
    num_samples: int = 1024
    subsets: tuple[str, ...] = TEST_SUBSETS
    limit: int | None = None  # first N scenes per subset; None: all
    physical_scenes: int | None = DEFAULT_PHYSICAL_SCENES  # first K scenes per subset; None: all, 0: none
    seed: int = 0
    chunk_size: int = 32  # scenes per `Method.run` call
    # Least grounding probability a method places against; 0: the paper's protocol (Table I), every
    # reference grounded at its argmax and the object always placed. The robot's gate is reported beside
    # Table I from each scene's confidence instead (eval/table.py, `selective_table`).
    threshold: float = 0.0

    def validate(self) -> None:
        """Raises EvaluationError naming every setting no evaluation can run with."""
        problems = [
            f"{name} must be at least {least}, got {value}"
            for name, least, value in (("num_samples", 1, self.num_samples), ("chunk_size", 1, self.chunk_size))
            if value < least
        ]
        if self.num_samples > MAX_SAMPLES:
            problems.append(f"num_samples must be at most {MAX_SAMPLES:,}, got {self.num_samples:,}")
        if self.limit is not None and self.limit < 1:
            problems.append(f"limit must be at least 1 (none: every scene), got {self.limit}")
        if self.physical_scenes is not None and self.physical_scenes < 0:
            problems.append(f"physical_scenes must be at least 0 (none: every scene), got {self.physical_scenes}")
        if self.seed < 0:
            problems.append(f"seed must be at least 0, got {self.seed}")
        if not 0.0 <= self.threshold <= 1.0:  # NaN fails too
            problems.append(f"threshold is a probability in [0, 1] (0: always place), got {self.threshold}")
        problems += [problem for problem in [subsets_problem(self.subsets, "subsets")] if problem]
        if problems:
            raise EvaluationError("cannot evaluate: " + "; ".join(problems))


@dataclasses.dataclass(frozen=True)
class MethodRun:
    """One row to evaluate: a method by its registered name, its Table I label and its trained run directory
    (None: nothing trained)."""

    method: str
    label: str
    run_dir: Path | None = None
    fraction: float = 1.0
    seed: int | None = None  # a repeat's own training and evaluation seed; None: the settings' seed
    backbone_seed: int | None = None  # a repeat on the backbone pretrained with this seed; None: the settings'
    backbone: str | None = None  # that backbone's spec, once known; None: the settings' backbone
    inference: InferenceSettings | None = None  # a policy row's placement-time settings; None: the row's own

    @property
    def key(self) -> str:
        key = self.method if self.fraction == 1.0 else f"{self.method}@{self.fraction:g}"
        key = key if self.seed is None else f"{key}~seed{self.seed}"
        return key if self.backbone_seed is None else f"{key}~backbone{self.backbone_seed}"

    def settings(self, settings: EvalSettings) -> EvalSettings:
        """The settings this run is scored with: its own seed and backbone, when it is a repeat."""
        if self.seed is not None:
            settings = dataclasses.replace(settings, seed=self.seed)
        return settings if self.backbone is None else dataclasses.replace(settings, backbone=self.backbone)


@dataclasses.dataclass(frozen=True)
class PhysicalOutcome:
    success: bool  # metric success and the drop check
    dropped: bool  # False: the metric already failed, nothing was dropped
    held_offset: float | None = None  # m
    max_disturbance: float | None = None  # m


@dataclasses.dataclass(frozen=True)
class SceneOutcome:
    """How one method did in one scene. `None` fields: the method does not report that part."""

    id: str
    level: str
    success: bool  # success of the mode
    sample_success: float  # mean success over samples; the mode's without samples; 0.0 on failure
    mode: tuple[float, float] | None
    num_samples: int
    failure: str | None
    parsed: tuple[tuple[str, str], ...] | None
    grounded: tuple[int, ...] | None  # object id per parsed tuple (0 = the table, -1 = not a token)
    parse_ok: bool | None
    grounding_ok: bool | None
    program_ok: bool | None  # the grounded problem equals the ground truth's
    stage: str | None  # where an unsuccessful scene went wrong (STAGES); None on success
    physical: PhysicalOutcome | None = None
    parse_note: str | None = None  # the LLM parser's fall-back reason or disagreement (MethodOutput.parse_note)
    confidence: float | None = None  # MethodOutput.confidence: the least top grounding probability
    # What the grounding knew (none of it is shown to a method; `None`: the method does not report it):
    probabilities: tuple[tuple[float, ...], ...] | None = None  # per parsed tuple, P per token (4 digits)
    token_names: tuple[str, ...] | None = None  # the library object of each token column, "table" last
    chosen_tokens: tuple[int, ...] | None = None  # per parsed tuple, the column the method grounded it to
    true_tokens: tuple[int | None, ...] | None = None  # per parsed tuple, its true reference's column (None: no
    # tuple of the ground truth matches the parsed one, or its object has no box)
    true_ranks: tuple[int | None, ...] | None = None  # 1 + the tokens more probable than the true one
    decision: str | None = None  # MethodOutput.decision: "argmax", "joint" or "joint_fallback"


@dataclasses.dataclass(frozen=True)
class Evaluation:
    """One method run scored on every subset."""

    key: str
    method: str
    label: str
    fraction: float
    run_dir: str | None
    description: dict[str, Any]  # the method's describe(), made JSON-able
    subsets: dict[str, tuple[SceneOutcome, ...]]
    wall_s: float
    seed: int | None = None  # MethodRun.seed
    backbone_seed: int | None = None  # MethodRun.backbone_seed
    backbone: str | None = None  # MethodRun.backbone: the spec of a backbone repeat's own backbone
    inference: InferenceSettings | None = None  # MethodRun.inference: the settings it placed with, when set


# ----------------------------------------------------------------------------- keys and scenes


def stable_id(name: str) -> int:
    return zlib.crc32(name.encode()) & 0x7FFFFFFF


def subset_key(seed: int, method: str, subset: str) -> jax.Array:
    """The jax.random key of one method on one subset: independent of the other methods and subsets."""
    import jax

    return jax.random.fold_in(jax.random.fold_in(jax.random.key(seed), stable_id(method)), stable_id(subset))


def subset_scenes(dataset_dir: Path, subset: str, limit: int | None) -> list[Any]:
    """The first `limit` (None: all) scenes the manifest lists for `subset`, as `ListedScene`s."""
    from ocplace.sim.dataset.job import listed_scenes

    scenes = listed_scenes(dataset_dir, subset)
    return scenes if limit is None else scenes[:limit]


def redacted(record: SceneRecord) -> SceneRecord:
    """The record without ground truth (tuples, their token indices, the oracle): what a method sees."""
    meta = {key: value for key, value in record.meta.items() if key != "oracle"} | {"tuples": []}
    return dataclasses.replace(record, meta=meta)


def chunks(scenes: Sequence[Any], size: int) -> Iterator[tuple[int, list[SceneRecord]]]:
    """`ListedScene`s read `size` at a time, each checked against its manifest hashes."""
    for index, start in enumerate(range(0, len(scenes), size)):
        yield index, [scene.read() for scene in scenes[start : start + size]]


# ----------------------------------------------------------------------------- running a method


def _describe_error(error: BaseException) -> str:
    return str(error) if isinstance(error, PolicyRaised) else f"{type(error).__name__}: {error}"


def _checked(outputs: object, count: int) -> list[MethodOutput]:
    if not isinstance(outputs, (list, tuple)) or len(outputs) != count:
        raise ValueError(
            f"run() returned {type(outputs).__name__} of length "
            f"{len(outputs) if hasattr(outputs, '__len__') else '?'} for {count} scenes"
        )
    return list(outputs)


def run_chunk(method: Method, scenes: Sequence[SceneRecord], key: jax.Array) -> list[MethodOutput]:
    """The method's outputs for `scenes`; an exception is pinned on the scene(s) that raise it."""
    import jax

    try:
        return _checked(method.run(scenes, key), len(scenes))
    except POLICY_ERRORS:
        if len(scenes) == 1:
            raise
    outputs = []
    for index, scene in enumerate(scenes):
        try:
            outputs.append(_checked(method.run([scene], jax.random.fold_in(key, index)), 1)[0])
        except POLICY_ERRORS as error:
            outputs.append(MethodOutput(mode=None, samples=None, failure=_describe_error(error)))
    return outputs


def run_scenes(method: Method, scenes: Sequence[SceneRecord], key: jax.Array) -> list[MethodOutput]:
    """`run_chunk`, with a single scene's exception turned into a failure."""
    try:
        return run_chunk(method, scenes, key)
    except POLICY_ERRORS as error:
        return [MethodOutput(mode=None, samples=None, failure=_describe_error(error))]


# ----------------------------------------------------------------------------- scoring one scene


def reference_key(phrase: str) -> str:
    """A reference phrase normalised like the parser normalises (lower case, articles dropped)."""
    from ocplace.models.parsing.text import normalise_reference

    return normalise_reference(phrase.lower().split())


def token_object_ids(boxes: Boxes, tokens: Sequence[int]) -> tuple[int, ...]:
    """Visual-token indices -> object ids, through the boxes' order; token N is the table (0)."""
    box_ids = [int(object_id) for object_id in boxes.object_ids]
    return tuple(box_ids[t] if 0 <= t < len(box_ids) else 0 if t == len(box_ids) else -1 for t in map(int, tokens))


def _same(a: Iterable[Any], b: Iterable[Any]) -> bool:
    return collections.Counter(a) == collections.Counter(b)


def _stage(failure: str | None, parse_ok: bool | None, grounding_ok: bool | None, program_ok: bool | None) -> str:
    if failure is not None:
        return "failure"
    if program_ok:
        return "sampling"
    if parse_ok is False:
        return "parse"
    if grounding_ok is False or program_ok is False:
        return "grounding"
    return "placement"  # the method reports neither parse nor grounding: an end-to-end miss


class _Interpreted(NamedTuple):
    mode: np.ndarray | None  # (2,)
    samples: np.ndarray | None  # (num_samples, 2)
    parsed: tuple[tuple[str, str], ...] | None
    tokens: tuple[int, ...] | None
    failure: str | None
    probabilities: np.ndarray | None = None  # (L, N + 1)


def _points(points: object, rows: bool) -> np.ndarray[Any, Any]:
    array = np.asarray(points, dtype=np.float64)
    if array.shape[-1:] != (2,) or (array.ndim != 2 if rows else array.ndim != 1) or not np.all(np.isfinite(array)):
        raise ValueError(f"expected finite {'(num_samples, 2)' if rows else '(2,)'} points, got shape {array.shape}")
    return array


def interpret(output: MethodOutput) -> _Interpreted:
    """The output's parts as plain arrays and tuples; anything malformed makes it a failure."""
    try:
        return _Interpreted(
            mode=None if output.mode is None else _points(output.mode, rows=False),
            samples=None if output.samples is None else _points(output.samples, rows=True),
            parsed=None if output.parsed is None else tuple((str(r), str(rel)) for r, rel in output.parsed),
            tokens=None if output.grounded is None else tuple(int(t) for t in output.grounded),
            failure=output.failure
            if output.failure is not None or output.mode is not None
            else "no placement and no failure message",
            probabilities=_probability_rows(output.probabilities),
        )
    except Exception as error:  # OverflowError (10**400), whatever an object's __array__ raises, ...
        return _Interpreted(None, None, None, None, output.failure or f"malformed output: {_describe_error(error)}")


def _probability_rows(rows: object) -> np.ndarray | None:
    """`(L, T)` float64 probabilities, or None when there are none; ValueError (a malformed output) otherwise."""
    if rows is None:
        return None
    array = np.asarray(rows, dtype=np.float64)
    if array.ndim != 2 or not np.all((array >= 0) & (array <= 1)):  # NaN fails too
        raise ValueError(f"probabilities must be (tuples, tokens) numbers in [0, 1], got shape {array.shape}")
    return array


def _compact(probability: float) -> float:
    """4 significant digits: about float16's, and a small outcomes file."""
    return float(f"{probability:.4g}")


def true_columns(
    parsed: Sequence[tuple[str, str]], truth: Sequence[Any], columns: Sequence[int]
) -> tuple[int | None, ...]:
    """Per parsed tuple, the token column of the ground truth's reference it stands for: the truth tuple of the same
    reference and relation, else of the same reference, else (as many tuples on both sides) the one at its place;
    None when none is left, or its object has no box. `columns`: the object id of each column."""
    keys = [(reference_key(t.reference_name), t.relation) for t in truth]
    unused = list(range(len(truth)))
    matched: list[int | None] = []
    for position, (reference, relation) in enumerate(parsed):
        key = (reference_key(reference), relation)
        found = next((i for i in unused if keys[i] == key), None)
        found = next((i for i in unused if keys[i][0] == key[0]), None) if found is None else found
        if found is None and len(parsed) == len(truth) and position in unused:
            found = position
        if found is not None:
            unused.remove(found)
        matched.append(found)
    column_of = {object_id: column for column, object_id in enumerate(columns)}
    return tuple(None if i is None else column_of.get(truth[i].reference_object_id) for i in matched)


def _grounding_record(
    record: SceneRecord,
    parsed: Sequence[tuple[str, str]] | None,
    tokens: Sequence[int] | None,
    probabilities: np.ndarray | None,
) -> dict[str, Any]:
    """The outcome's record of what the grounding knew: each parsed tuple's probabilities, each column's object,
    the chosen and the true column and its rank; empty when the method reports no probabilities for its tuples."""
    columns = (*(int(object_id) for object_id in record.boxes.object_ids), 0)
    if probabilities is None or parsed is None or probabilities.shape != (len(parsed), len(columns)):
        return {}
    names = {obj.object_id: obj.name for obj in record.objects} | {0: "table"}
    true = true_columns(parsed, record.tuples or (), columns)
    ranks = tuple(
        None if column is None else 1 + int(np.sum(row > row[column])) for row, column in zip(probabilities, true)
    )
    return {
        "probabilities": tuple(tuple(_compact(p) for p in row) for row in probabilities),
        "token_names": tuple(names.get(object_id, "?") for object_id in columns),
        "chosen_tokens": None if tokens is None or len(tokens) != len(parsed) else tuple(tokens),
        "true_tokens": true,
        "true_ranks": ranks,
    }


def score_scene(record: SceneRecord, output: MethodOutput) -> SceneOutcome:
    """Scores one output against the record's ground truth (no physical check)."""
    from ocplace.sim.metric import placement_success

    truth = record.tuples or ()
    if not isinstance(output, MethodOutput):  # anyone's Method may return anything
        output = MethodOutput(None, None, failure=f"malformed output: {type(output).__name__}, not a MethodOutput")
    mode, samples, parsed, tokens, failure, probabilities = interpret(output)
    problem = record.problem()
    success = failure is None and mode is not None and bool(placement_success(mode[None], problem)[0])
    if failure is not None:
        sample_success = 0.0
    elif samples is None or len(samples) == 0:
        sample_success = float(success)  # a method without samples: a point mass at its mode
    else:
        sample_success = float(np.mean(placement_success(samples, problem)))

    grounded = None if tokens is None else token_object_ids(record.boxes, tokens)
    truth_pairs = [(reference_key(t.reference_name), t.relation) for t in truth]
    truth_ids = [t.reference_object_id for t in truth]
    parse_ok = None if parsed is None else _same([(reference_key(r), rel) for r, rel in parsed], truth_pairs)
    grounding_ok = None if grounded is None else _same(grounded, truth_ids)
    program_ok = None
    if parsed is not None and grounded is not None:
        program_ok = len(parsed) == len(grounded) and _same(
            zip(grounded, (rel for _, rel in parsed)), zip(truth_ids, (t.relation for t in truth))
        )
    return SceneOutcome(
        id=record.id,
        level=record.level,
        success=success,
        sample_success=sample_success,
        mode=None if mode is None else (float(mode[0]), float(mode[1])),
        num_samples=0 if samples is None else len(samples),
        failure=failure,
        parsed=parsed,
        grounded=grounded,
        parse_ok=parse_ok,
        grounding_ok=grounding_ok,
        program_ok=program_ok,
        stage=None if success else _stage(failure, parse_ok, grounding_ok, program_ok),
        parse_note=output.parse_note if isinstance(output.parse_note, str) else None,
        confidence=_probability(output.confidence),
        decision=output.decision if isinstance(output.decision, str) else None,
        **_grounding_record(record, parsed, tokens, probabilities),
    )


def _probability(value: object) -> float | None:
    """`value` as a float in [0, 1], or None when it is missing or not a probability."""
    try:
        number = float(value)  # type: ignore[arg-type]  # anything a Method returned; not a number: None
    except (TypeError, ValueError):
        return None
    return number if 0.0 <= number <= 1.0 else None


def physical_outcome(arena: MujocoScenes, record: SceneRecord, outcome: SceneOutcome) -> PhysicalOutcome:
    """Physical success = metric success and the drop check; nothing is dropped when the metric failed."""
    from ocplace.sim.physical import physical_check

    if not outcome.success:
        return PhysicalOutcome(success=False, dropped=False)
    result = physical_check(arena, record, np.asarray(outcome.mode))
    return PhysicalOutcome(bool(result.success), True, float(result.held_offset), float(result.max_disturbance))


# ----------------------------------------------------------------------------- a method on the test subsets


def evaluate_subset(
    method: Method,
    name: str,
    dataset_dir: Path,
    subset: str,
    settings: EvalSettings,
    arena: MujocoScenes | None = None,
    progress: bool = True,
) -> tuple[SceneOutcome, ...]:
    """Every scene of `subset` (up to `settings.limit`), scored; the first K also physically."""
    import jax

    from ocplace.runtime.progress import progress_bar

    scenes = subset_scenes(dataset_dir, subset, settings.limit)
    physical_limit = len(scenes) if settings.physical_scenes is None else settings.physical_scenes
    base_key = subset_key(settings.seed, name, subset)
    outcomes: list[SceneOutcome] = []
    bar = progress_bar(total=len(scenes), desc=f"{name} {subset}", unit="scene", enabled=progress, leave=False)
    for chunk_index, records in chunks(scenes, settings.chunk_size):
        outputs = run_scenes(method, [redacted(r) for r in records], jax.random.fold_in(base_key, chunk_index))
        for record, output in zip(records, outputs):
            outcome = score_scene(record, output)
            if arena is not None and len(outcomes) < physical_limit:
                outcome = dataclasses.replace(outcome, physical=physical_outcome(arena, record, outcome))
            outcomes.append(outcome)
        bar.update(len(records))
    bar.close()
    return tuple(outcomes)


def evaluate_run(
    run: MethodRun,
    method: Method,
    dataset_dir: str | Path,
    settings: EvalSettings,
    arena: MujocoScenes | None = None,
    progress: bool = True,
) -> Evaluation:
    """Scores `method`, loaded from `run`, on every subset of `settings`.

    The physical check runs for runs on the whole training set only (fractions feed the
    sample-efficiency curve, which plots the metric).
    """
    began = time.perf_counter()
    settings = run.settings(settings)
    arena = arena if run.fraction == 1.0 else None
    subsets = {
        subset: evaluate_subset(method, run.method, Path(dataset_dir), subset, settings, arena, progress)
        for subset in settings.subsets
    }
    return Evaluation(
        key=run.key,
        method=run.method,
        label=run.label,
        fraction=run.fraction,
        run_dir=None if run.run_dir is None else str(run.run_dir),
        description=serial.to_dict(method.describe()),
        subsets=subsets,
        wall_s=time.perf_counter() - began,
        seed=run.seed,
        backbone_seed=run.backbone_seed,
        backbone=run.backbone,
        inference=run.inference,
    )


def evaluate_in_own_arena(
    run: MethodRun, method: Method, dataset_dir: str | Path, settings: EvalSettings
) -> Evaluation:
    """`evaluate_run` with its own physical arena (for runs on the whole training set), as a task does it."""
    checked = run.settings(settings)
    if run.fraction != 1.0:
        checked = dataclasses.replace(checked, physical_scenes=0)
    with physical_arena(checked, dataset_dir) as arena:
        return evaluate_run(run, method, dataset_dir, settings, arena, progress=True)


# ----------------------------------------------------------------------------- aggregates


def _rate(values: list[Any]) -> float | None:
    known = [float(v) for v in values if v is not None]
    return float(np.mean(known)) if known else None


def aggregate(outcomes: Sequence[SceneOutcome]) -> dict[str, Any]:
    """Rates (0..1) over `outcomes`; a rate is None when no scene reports that part."""
    physical = [o.physical for o in outcomes if o.physical is not None]
    stages = collections.Counter(o.stage for o in outcomes if o.stage is not None)
    return {
        "scenes": len(outcomes),
        "success": _rate([o.success for o in outcomes]),
        "sample_success": _rate([o.sample_success for o in outcomes]),
        "physical_scenes": len(physical),
        "physical_success": _rate([p.success for p in physical]),
        "physical_mode_success": _rate([o.success for o in outcomes if o.physical is not None]),
        "parse_accuracy": _rate([o.parse_ok for o in outcomes]),
        "grounding_accuracy": _rate([o.grounding_ok for o in outcomes]),
        "program_accuracy": _rate([o.program_ok for o in outcomes]),
        "failures": stages.get("failure", 0),
        "stages": {stage: stages.get(stage, 0) for stage in STAGES},
    }


def aggregate_subset(outcomes: Sequence[SceneOutcome]) -> dict[str, Any]:
    """Per level, `objects` (the object-referenced levels pooled: 1 Obj and 2 Obj) and `overall` (pooled over
    the subset's scenes, as the paper's Overall column)."""
    by_level = {level: aggregate([o for o in outcomes if o.level in LEVEL_GROUPS[level]]) for level in LEVEL_GROUPS}
    return by_level | {"overall": aggregate(outcomes)}


@contextlib.contextmanager
def physical_arena(settings: EvalSettings, dataset_dir: str | Path) -> Iterator[MujocoScenes | None]:
    """The MuJoCo arena for the physical check of `dataset_dir`'s scenes (with the library they were made with: a
    user catalogue's objects for its subsets), or None when `settings` asks for no physical check."""
    if settings.physical_scenes == 0:
        yield None
        return
    from ocplace.sim.dataset.job import library_of_dataset
    from ocplace.sim.mujoco_backend import MujocoScenes

    with MujocoScenes.from_library(library_of_dataset(dataset_dir)) as arena:
        yield arena
