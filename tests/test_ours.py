"""Table I's "Ours" and "Ours w/o Adapter" as evaluation methods (methods/ours/, methods/no_adapter/, on
methods/policy_method.py)."""

import dataclasses
import json

import jax
import numpy as np
import pytest
from llm_endpoint import fixed_answer, llm_parser

from ocplace import serial
from ocplace.errors import TrainingError
from ocplace.eval.api import MethodOutput
from ocplace.eval.harness import SceneOutcome, score_scene
from ocplace.methods.contract import LoadContext
from ocplace.methods.ours import method as ours
from ocplace.methods.registry import method_specs
from ocplace.paths import RUN_FILE
from ocplace.sim.dataset.job import scene_dirs
from ocplace.sim.dataset.records import SceneRecord, read_scene


def _without_ground_truth(record: SceneRecord) -> SceneRecord:
    """A method must not read tuples, the oracle or token indices: remove them."""
    meta = {k: v for k, v in record.meta.items() if k not in ("tuples", "oracle")}
    return dataclasses.replace(record, meta=meta)


@pytest.fixture(scope="module")
def seen_records(smoke_dataset):
    return [_without_ground_truth(read_scene(d)) for d in scene_dirs(smoke_dataset, "seen")]


def test_methods_are_registered():
    specs = method_specs()
    assert specs["ours"].label == "Ours" and specs["ours"].train is ours.train
    assert specs["no_adapter"].label == "Ours w/o Adapter" and specs["no_adapter"].train is None


def test_ours_trains_at_smoke_scale_and_places_every_scene(trained_run, tiny_backbone_spec, seen_records):
    run, features = trained_run
    assert len(features) == 1  # the training split's features, cached where `ocplace featurize` puts them
    config = json.loads((run / RUN_FILE).read_text())
    assert config["train_config"]["fraction"] == 0.5 and config["train_config"]["seed"] == 3
    assert config["train_scenes"] == 6  # half of the 12 smoke training scenes

    method = method_specs()["ours"].load(LoadContext(run, tiny_backbone_spec, num_samples=128))
    outputs = method.run(seen_records, jax.random.key(0))
    assert len(outputs) == len(seen_records)
    for record, output in zip(seen_records, outputs):
        assert isinstance(output, MethodOutput)
        assert output.parsed and len(output.grounded) == len(output.parsed)
        num_tokens = len(record.boxes) + 1
        assert all(0 <= token < num_tokens for token in output.grounded)
        # The paper's protocol never refuses: a wrong grounding may still leave no feasible region, or ask an
        # object relation of "the table", which are typed failures.
        assert (output.mode is None) == (output.failure is not None)
        assert 0.0 <= output.confidence <= 1.0
        assert output.confidence == pytest.approx(min(max(row) for row in _probabilities(method, record)), abs=1e-4)
        if output.mode is None:
            assert output.failure.split(":")[0] in ("NoFeasiblePlacement", "InvalidPlacementProblem")
            assert output.samples is None
        else:
            assert output.samples.shape == (128, 2)

    # The robot's gate refuses exactly the scenes whose confidence is below its threshold.
    gated = method_specs()["ours"].load(LoadContext(run, tiny_backbone_spec, num_samples=128, threshold=0.5))
    for output, gated_output in zip(outputs, gated.run(seen_records, jax.random.key(0))):
        refused = gated_output.failure is not None and gated_output.failure.startswith("GroundingUncertain")
        assert refused == (output.confidence < 0.5)

    description = method.describe()
    text = json.dumps(description)
    assert description["adapters"]["steps"] == 300 and len(description["adapters"]["sha256"]) == 64
    assert description["backbone"]["fingerprint"] and description["parser"]["name"] == "offline"
    assert description["threshold"] == method.policy.threshold and "sampler" in text


def _probabilities(method, record):
    """Each parsed reference's P over the visual tokens, from the policy's own stages."""
    from ocplace.methods.policy_method import scene_input

    policy = method.policy
    prepared = policy.prepare(scene_input(record))
    parsed = policy.parse(record.instruction)
    probabilities = policy.ground(policy.encode([prepared], [parsed]))[0]
    return [probabilities[k, : len(prepared.boxes) + 1] for k in range(len(parsed))]


def test_no_adapter_places_with_zero_threshold(tiny_backbone_spec, seen_records):
    method = method_specs()["no_adapter"].load(LoadContext(None, tiny_backbone_spec, num_samples=128))
    assert method.policy.threshold == 0.0  # an evaluation places always (the paper's protocol)
    outputs = method.run(seen_records[:4], jax.random.key(0))
    assert len(outputs) == 4
    assert any(o.mode is not None for o in outputs)
    for output in outputs:
        if output.mode is not None:
            assert np.all(np.abs(output.mode) <= [0.4, 0.3])
        else:  # a wrong grounding may leave no feasible region; it is reported, not placed
            assert "NoFeasiblePlacement" in output.failure or "InvalidPlacementProblem" in output.failure
    description = method.describe()
    assert description["adapters"] is None and description["grounding"]["zero_shot"]
    json.dumps(description)


def test_ours_without_a_run_says_to_train_first(tiny_backbone_spec, tmp_path):
    with pytest.raises(TrainingError, match="train the 'ours' method first"):
        method_specs()["ours"].load(LoadContext(tmp_path, tiny_backbone_spec))


def test_pipeline_draws_ours_on_the_first_seen_scene(trained_run, smoke_dataset, tiny_backbone_spec, tmp_path):
    from ocplace.experiments import pipeline

    path = tmp_path / "placement.png"
    detail = pipeline.placement_figure_task(trained_run[0], "offline", 0, smoke_dataset, tiny_backbone_spec, path)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert detail.startswith(f"{path} (seen-00000, ")


def test_results_say_when_the_llm_parser_fell_back_or_disagreed(tiny_backbone_spec, smoke_dataset, seen_records):
    method = method_specs()["no_adapter"].load(LoadContext(None, tiny_backbone_spec, num_samples=64))
    truths = [read_scene(d) for d in scene_dirs(smoke_dataset, "seen")[:2]]

    def outcomes():
        outputs = method.run(seen_records[:2], jax.random.key(0))
        return [score_scene(truth, output) for truth, output in zip(truths, outputs)]

    plain = outcomes()
    assert all(outcome.parse_note is None for outcome in plain)
    with fixed_answer(500) as endpoint:
        method.policy = dataclasses.replace(method.policy, parser=llm_parser(endpoint, method.policy.parser))
        fell_back = outcomes()
        endpoint.answer = json.dumps({"tuples": [{"reference": "unicorn", "relation": "left"}]})
        disagreed = outcomes()

    for before, after in zip(plain, fell_back):
        assert after.parsed == before.parsed and "HTTP 500" in after.parse_note
    for outcome in disagreed:  # the cross-check keeps the offline parse and says why
        assert "unicorn" in outcome.parse_note and ("unicorn", "left") not in outcome.parsed
    assert serial.from_dict(SceneOutcome, json.loads(serial.to_json(disagreed[0]))) == disagreed[0]
