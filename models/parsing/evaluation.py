"""Parser evaluation: seen and unseen generated instructions and the hand-written free-form set.

Accuracy counts an instruction right when its set of `(reference, relation)` pairs equals the
expected set (order-insensitive), or, for bad input, when the parser raises ParseError.
"""

from __future__ import annotations

import dataclasses
import enum
import json
import time
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np

from ocplace.errors import LLMUnreachable, ParseError
from ocplace.models.parsing import crosscheck, text
from ocplace.models.parsing.config import CROSS_CHECK_POLICIES
from ocplace.models.parsing.types import ParsedTuple, Parser, as_pairs
from ocplace.sim import language, relations

# Stand-in tabletop object names until the library's own names are passed in: plain nouns,
# colours, materials, "of"-phrases, "with"-attributes and a possessive, as a real library has.
EVAL_OBJECT_NAMES: tuple[str, ...] = (
    "alphabet soup can",
    "red bowl",
    "rubber duck",
    "black shoe with green stripes",
    "blue mug",
    "white mug",
    "tomato sauce can",
    "ketchup bottle",
    "mustard bottle",
    "cream cheese box",
    "butter stick",
    "chocolate pudding box",
    "milk carton",
    "orange juice carton",
    "salad dressing bottle",
    "bbq sauce bottle",
    "green apple",
    "banana",
    "lemon",
    "orange",
    "peach",
    "pear",
    "strawberry",
    "plum",
    "yellow sponge",
    "toy airplane",
    "wooden block",
    "tennis ball",
    "baseball",
    "rubik's cube",
    "spiderman figure",
    "teddy bear",
    "toy car",
    "plastic cup",
    "coffee mug",
    "ceramic plate",
    "soap bottle",
    "toothpaste box",
    "power drill",
    "pair of scissors",
    "screwdriver",
    "hammer",
    "marker",
    "stapler",
    "roll of tape",
    "padlock",
    "alarm clock",
    "sunglasses",
    "baseball cap",
    "wooden spoon",
)
FREEFORM_PATH = Path(__file__).resolve().parents[2] / "tests" / "data" / "freeform_instructions.jsonl"
LEVEL_WEIGHTS = {"table": 9, "1obj": 9, "2obj": 22}  # the test subsets' ratio (docs/design.md#dataset)
MAX_TRANSPORT_FAILURES = 3  # instructions in a row without an answer, for transport reasons, before stopping


@dataclasses.dataclass(frozen=True)
class Case:
    instruction: str
    expected: frozenset[tuple[str, str]]  # empty when a ParseError is expected
    expects_error: bool = False
    note: str = ""


@dataclasses.dataclass(frozen=True)
class Report:
    name: str
    num_cases: int
    num_correct: int
    latency_ms: tuple[float, float, float]  # mean, median, 95th percentile per instruction
    failures: tuple[tuple[str, str, str], ...]  # (instruction, expected, got)

    @property
    def accuracy(self) -> float:
        return self.num_correct / max(self.num_cases, 1)

    def summary(self) -> str:
        mean, median, p95 = self.latency_ms
        return (
            f"{self.name:12s} {self.accuracy * 100:6.2f}% ({self.num_correct}/{self.num_cases})"
            f"  latency ms: mean {mean:.3f}, median {median:.3f}, p95 {p95:.3f}"
        )


def sample_reference_tuples(
    level: str, names: Sequence[str], rng: np.random.Generator
) -> tuple[language.ReferenceTuple, ...]:
    """Random tuples for one instruction of `level` ("table", "1obj", "2obj")."""
    if level == "table":
        relation = relations.RELATION_NAMES[int(rng.integers(len(relations.RELATION_NAMES)))]
        return (language.ReferenceTuple(language.TABLE_NAME, relation, True),)
    count = {"1obj": 1, "2obj": 2}[level]
    picked = rng.choice(len(names), size=count, replace=False)
    object_relations = relations.OBJECT_RELATION_NAMES
    return tuple(
        language.ReferenceTuple(names[int(i)], object_relations[int(rng.integers(len(object_relations)))], False)
        for i in picked
    )


def generated_cases(style: str, num_cases: int, seed: int, names: Sequence[str] = EVAL_OBJECT_NAMES) -> list[Case]:
    """Instructions rendered by `sim.language` with levels in the test subsets' ratio."""
    rng = np.random.default_rng(seed)
    levels = list(LEVEL_WEIGHTS)
    weights = np.array(list(LEVEL_WEIGHTS.values()), dtype=float)
    cases = []
    for _ in range(num_cases):
        level = levels[int(rng.choice(len(levels), p=weights / weights.sum()))]
        tuples = sample_reference_tuples(level, names, rng)
        instruction = language.render_instruction(tuples, style, rng)
        expected = frozenset((text.normalise_reference(t.name.split()), t.relation) for t in tuples)
        cases.append(Case(instruction, expected, note=level))
    return cases


def freeform_cases(path: Path = FREEFORM_PATH, split: str | None = None) -> list[Case]:
    """The hand-written set; `split` keeps one part: "dev" (parser developed on it), "test"
    (written with dev, first scored after development), "blind" (written after the parser)."""
    cases = []
    for line in Path(path).read_text(encoding="utf-8").splitlines():
        record = json.loads(line)
        if split and record["split"] != split:
            continue
        expected = frozenset((t["reference"], t["relation"]) for t in record["tuples"])
        cases.append(Case(record["instruction"], expected, bool(record.get("error")), record.get("note", "")))
    return cases


def evaluate(parser: Parser, cases: Iterable[Case], name: str) -> Report:
    """Accuracy and per-instruction latency of `parser` on `cases`."""
    correct, latencies, failures = 0, [], []
    for case in cases:
        start = time.perf_counter()
        try:
            got: frozenset | str = frozenset(as_pairs(parser.parse(case.instruction)))
        except ParseError as error:
            got = f"ParseError: {error}"
        latencies.append((time.perf_counter() - start) * 1e3)
        right = isinstance(got, str) if case.expects_error else got == case.expected
        correct += right
        if not right:
            expected = "ParseError" if case.expects_error else str(sorted(case.expected))
            got_text = got if isinstance(got, str) else str(sorted(got))
            failures.append((case.instruction, expected, got_text))
    values = np.array(latencies or [0.0])
    return Report(
        name,
        len(latencies),
        correct,
        (float(values.mean()), float(np.median(values)), float(np.percentile(values, 95))),
        tuple(failures),
    )


class _Missing(enum.Enum):
    """An answer slot the LLM left empty: it gave no valid answer, and the parser fell back."""

    NO_ANSWER = enum.auto()


_NO_ANSWER = _Missing.NO_ANSWER


@dataclasses.dataclass(frozen=True)
class LLMReport:
    """The LLM parser on one set: the LLM's own answers, the offline parse, and what each cross-check policy
    answers. Keys: "llm alone" (its own valid answers; none is wrong), "offline alone", and "cross-check P"
    for each policy P (a fall-back to the offline parser included)."""

    name: str
    num_cases: int
    correct: dict[str, int]
    silent_drops: dict[str, int]  # answers naming fewer of the expected references, with no disagreement said
    fallbacks: int  # no valid answer from the LLM: every policy answers with the offline parse
    request_ms: tuple[float, float]  # median and 95th percentile of the LLM's answer time

    def summary(self) -> str:
        scores = ", ".join(
            f"{key} {self.correct[key] / max(self.num_cases, 1):.1%} ({self.silent_drops[key]} silent drops)"
            for key in self.correct
        )
        median, p95 = self.request_ms
        return (
            f"{self.name:12s} n={self.num_cases}: {scores}; no valid LLM answer {self.fallbacks}; "
            f"LLM answer ms: median {median:.0f}, p95 {p95:.0f}"
        )


def evaluate_llm(parser, cases: Iterable[Case], name: str) -> LLMReport:
    """`parser` (an LLMParser) asked once per case; every policy is scored on the same answers.

    Raises LLMUnreachable once MAX_TRANSPORT_FAILURES instructions in a row got no answer for transport
    reasons: a dead endpoint would otherwise cost the whole deadline per instruction (hours for a set)."""
    from ocplace.models.parsing.llm import NoAnswer

    keys = ("llm alone", "offline alone", *(f"cross-check {policy}" for policy in CROSS_CHECK_POLICIES))
    correct, drops = dict.fromkeys(keys, 0), dict.fromkeys(keys, 0)
    fallbacks, request_ms, num_cases = 0, [], 0
    for case in cases:
        num_cases += 1
        answers: dict[str, list[ParsedTuple] | _Missing | None] = dict.fromkeys(keys)  # None: a ParseError
        try:
            cleaned = text.validate(case.instruction)
        except ParseError:
            cleaned = None
        if cleaned is not None:
            start = time.perf_counter()
            try:
                own = parser.answer(cleaned)
            except NoAnswer as error:
                own = None
                if parser.unreachable_in_a_row >= MAX_TRANSPORT_FAILURES:  # counted across sets
                    raise LLMUnreachable(
                        f"the LLM endpoint {parser.config.base_url} gave no answer to {parser.unreachable_in_a_row} "
                        f"instructions in a row ({error}); stopped rather than wait the deadline for every "
                        "instruction. Check that the server runs (`make llm-server`) and --base-url, then rerun"
                    ) from None
            request_ms.append((time.perf_counter() - start) * 1e3)
            fallbacks += own is None
            answers = _answers_by_policy(parser, cleaned, own)
        for key, answer in answers.items():
            correct[key] += _right(case, answer)
            drops[key] += _silent_drop(case, answer)
    values = np.array(request_ms or [0.0])
    return LLMReport(
        name, num_cases, correct, drops, fallbacks, (float(np.median(values)), float(np.percentile(values, 95)))
    )


def _answers_by_policy(parser, instruction: str, own) -> dict:
    try:
        offline, offline_error = parser.offline.parse(instruction), None
    except ParseError as error:
        offline, offline_error = None, str(error)
    # No valid answer is wrong even where a ParseError is right: the LLM did not refuse, it failed.
    answers = {"llm alone": _NO_ANSWER if own is None else own or None, "offline alone": offline}
    comparison = crosscheck.compare(own, offline, offline_error) if own is not None else None
    for policy in CROSS_CHECK_POLICIES:
        chosen = offline if own is None or comparison is None else crosscheck.choose(policy, own, offline, comparison)
        answers[f"cross-check {policy}"] = chosen or None
    return answers


def _right(case: Case, answer) -> bool:
    if answer is _NO_ANSWER:
        return False
    if case.expects_error:
        return answer is None
    return answer is not None and frozenset(as_pairs(answer)) == case.expected


def _silent_drop(case: Case, answer) -> bool:
    """The answer leaves out a reference the instruction names, and says nothing about it."""
    if case.expects_error or answer is None or answer is _NO_ANSWER or answer[0].disagreement is not None:
        return False
    expected = [ParsedTuple(name, relation, "expected") for name, relation in sorted(case.expected)]
    return bool(crosscheck.compare(answer, expected).dropped)


@dataclasses.dataclass(frozen=True)
class ExpressionSnap:
    expression: str
    relation: str  # what the expression means
    nearest: str  # the encoder's closest canonical relation
    similarity: float
    margin: float
    accepted: bool  # passes the snapper's thresholds


def expression_snapping(snapper) -> list[ExpressionSnap]:
    """How the encoder alone snaps each of the 25 unseen relation expressions."""
    out = []
    for relation, expressions in language.UNSEEN_RELATION_EXPRESSIONS.items():
        for expression in expressions:
            best = snapper.nearest(expression)
            try:
                snapper.snap(expression)
                accepted = True
            except ParseError:
                accepted = False
            out.append(ExpressionSnap(expression, relation, best.relation, best.similarity, best.margin, accepted))
    return out
