"""Joint, feasibility-aware grounding (models/joint_grounding.py) against a brute force on the NumPy metric."""

import itertools

import numpy as np
import pytest
from synthetic_problems import random_boxes

from ocplace.errors import ConfigError, InvalidPlacementProblem
from ocplace.models.inference_settings import Decision, InferenceSettings
from ocplace.models.joint_grounding import JointProblem, choose_assignments
from ocplace.sim import metric, relations

NAMES = ("mug", "bowl", "shoe", "table")


def random_scene(rng, num_tuples: int, num_tokens: int):
    """One scene's fields (no scene axis): random probabilities over N objects and the table, random names and
    relations (some table-only), boxes that may leave no room."""
    num_boxes = int(rng.integers(0, num_tokens))
    boxes = random_boxes(rng, num_boxes).astype(np.float32)
    used = np.arange(4) < num_tuples
    probabilities = np.zeros((4, num_tokens), np.float32)
    probabilities[:, : num_boxes + 1] = rng.dirichlet(np.full(num_boxes + 1, 0.6), size=4)
    names = [str(rng.choice(NAMES)) for _ in range(num_tuples)] + [None] * (4 - num_tuples)
    token_boxes = np.zeros((num_tokens, 2, 2), np.float32)
    token_boxes[:num_boxes] = boxes
    return JointProblem(
        probabilities=np.where(used[:, None], probabilities, 0).astype(np.float32),
        tuple_mask=used,
        relation=rng.integers(0, len(relations.RELATION_NAMES), 4).astype(np.int32),
        same_name=np.array([[a == b for b in names] for a in names]),
        num_boxes=np.int32(num_boxes),
        token_boxes=token_boxes,
        boxes=np.concatenate([boxes, np.zeros((num_tokens - 1 - num_boxes, 2, 2), np.float32)]),
        box_mask=np.arange(num_tokens - 1) < num_boxes,
        half_extents=rng.uniform(0.01, 0.06, 2).astype(np.float32),
    )


def stacked(scenes):
    return JointProblem(*(np.stack(field) for field in zip(*scenes)))


def feasible_by_metric(scene: JointProblem, tokens) -> bool:
    """The oracle: the NumPy metric's feasible grid for the tuples grounded on `tokens`."""
    count = int(scene.num_boxes)
    tuples = [
        metric.GroundedTuple(relations.RELATION_NAMES[scene.relation[k]], None if t == count else scene.token_boxes[t])
        for k, t in enumerate(tokens)
    ]
    try:
        problem = metric.encode_problem(tuples, scene.boxes[:count], scene.half_extents)
    except InvalidPlacementProblem:  # an object relation asked of the table's region, or the reverse
        return False
    return bool(metric.feasible_grid(problem).any())


def brute_force(scene: JointProblem, top_k: int):
    """(tokens, found): the consistent feasible assignment of highest joint probability, else the argmax one."""
    used = int(scene.tuple_mask.sum())
    rows = np.asarray(scene.probabilities[:used], np.float64)
    candidates = [np.argsort(-row, kind="stable")[: min(top_k, row.size)] for row in rows]
    argmax = tuple(int(c[0]) for c in candidates)
    best, best_log_p = None, -np.inf
    for tokens in itertools.product(*candidates):
        tokens = tuple(int(t) for t in tokens)
        if any(rows[k, t] == 0 for k, t in enumerate(tokens)):
            continue
        consistent = all(
            (tokens[a] == tokens[b])
            if scene.same_name[a, b]
            else (tokens[a] != tokens[b] or tokens[a] == scene.num_boxes)
            for a in range(used)
            for b in range(used)
        )
        if not consistent or not feasible_by_metric(scene, tokens):
            continue
        log_p = float(np.sum(np.log(rows[np.arange(used), tokens])))
        if log_p > best_log_p + 1e-6:
            best, best_log_p = tokens, log_p
    return (argmax, False) if best is None else (best, True)


# top_k 3 and 9 in the slow suite: the default suite's 15 min budget on 2 cores (docs/performance.md, session 12).
@pytest.mark.parametrize("top_k", [1, 2, *(pytest.param(k, marks=pytest.mark.slow) for k in (3, 9))])
def test_the_choice_is_the_most_probable_consistent_feasible_assignment(top_k):
    rng = np.random.default_rng(top_k)
    for num_tuples in (1, 2, 3):
        scenes = [random_scene(rng, num_tuples, num_tokens=7) for _ in range(24)]
        problem = stacked(scenes)
        problem = problem._replace(
            probabilities=problem.probabilities[:, :num_tuples],
            tuple_mask=problem.tuple_mask[:, :num_tuples],
            relation=problem.relation[:, :num_tuples],
            same_name=problem.same_name[:, :num_tuples, :num_tuples],
        )
        choice = choose_assignments(problem, top_k)
        found_any = False
        for index, scene in enumerate(scenes):
            tokens, found = brute_force(scene, top_k)
            assert bool(choice.found[index]) == found, (num_tuples, index)
            assert tuple(int(t) for t in choice.tokens[index, :num_tuples]) == tokens, (num_tuples, index)
            if found:  # the sampler's support is not empty for the chosen tuples
                assert feasible_by_metric(scene, tokens)
            found_any |= found
        assert found_any  # the random scenes are not all hopeless: the comparison tests something


def test_different_names_take_different_objects_and_the_same_name_the_same_token():
    num_tokens = 4  # three objects and the table
    boxes = np.array([[[-0.3, -0.2], [-0.25, -0.15]], [[0.0, 0.0], [0.05, 0.05]], [[0.25, 0.15], [0.3, 0.2]]])
    token_boxes = np.zeros((num_tokens, 2, 2), np.float32)
    token_boxes[:3] = boxes

    def scene(names, probabilities):
        return JointProblem(
            probabilities=np.asarray(probabilities, np.float32),
            tuple_mask=np.ones(2, bool),
            relation=np.full(2, relations.relation_index("back"), np.int32),  # a relation any token can take
            same_name=np.array([[a == b for b in names] for a in names]),
            num_boxes=np.int32(3),
            token_boxes=token_boxes,
            boxes=token_boxes[:3],
            box_mask=np.ones(3, bool),
            half_extents=np.full(2, 0.01, np.float32),
        )

    both_on_one = [[0.1, 0.7, 0.15, 0.05], [0.1, 0.6, 0.25, 0.05]]
    choice = choose_assignments(stacked([scene(["mug", "bowl"], both_on_one), scene(["mug", "mug"], both_on_one)]), 3)
    assert choice.tokens[0].tolist() == [1, 2]  # 0.7 * 0.25 beats 0.15 * 0.6: the bowl is not the mug
    assert choice.tokens[1].tolist() == [1, 1]  # one name, one object
    assert choice.found.all() and choice.consistent[0] < 9

    table_twice = [[0.1, 0.1, 0.1, 0.7], [0.1, 0.1, 0.1, 0.7]]
    choice = choose_assignments(stacked([scene(["table", "desk"], table_twice)]), 2)
    assert choice.tokens[0].tolist() == [3, 3]  # the table is no object: two names may both take it


def test_no_feasible_assignment_keeps_the_argmax_one_and_says_so():
    rng = np.random.default_rng(7)
    crowded = random_scene(rng, 2, num_tokens=7)._replace(half_extents=np.full(2, 0.45, np.float32))  # never fits
    only_table = np.zeros((4, 7), np.float32)
    only_table[0, 0] = 1.0  # no boxes: token 0 is the table
    no_boxes = random_scene(rng, 1, num_tokens=7)._replace(
        probabilities=only_table, num_boxes=np.int32(0), box_mask=np.zeros(6, bool)
    )
    choice = choose_assignments(stacked([crowded, no_boxes]), 5)
    assert not choice.found[0] and choice.feasible[0] == 0
    assert choice.tokens[0, :2].tolist() == np.argmax(crowded.probabilities[:2], axis=1).tolist()
    assert choice.tokens[1, 0] == 0  # no boxes: the table is the only token, whatever k asks


def test_settings_refuse_what_the_search_cannot_do():
    assert not InferenceSettings(Decision("joint", top_k=8)).problems()  # 8 ** 4 = 4096: the limit itself
    problems = InferenceSettings(Decision("joint", top_k=9)).problems()
    assert len(problems) == 1 and "6,561 assignments" in problems[0] and "lower top_k or max_tuples" in problems[0]
    assert not InferenceSettings(Decision("joint", top_k=9), max_tuples=3).problems()
    for bad in (Decision("joint", top_k=0), Decision("joint", top_k=17), Decision("greedy"), Decision(top_k=2.5)):
        with pytest.raises(ConfigError, match="decision"):
            InferenceSettings(bad).validate()
    with pytest.raises(ConfigError, match="max_tuples"):
        InferenceSettings(max_tuples=5).validate()
