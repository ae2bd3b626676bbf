"""Issue 57's plumbing: rows that place with another row's runs, inference settings per row, every reference's
probabilities in the outcomes, and differences between rows paired on the same scenes and runs."""

import dataclasses
import json

import jax
import numpy as np
import pytest

from ocplace import configs
from ocplace.cli.options import apply_overrides
from ocplace.errors import ConfigError, PolicyFolderError
from ocplace.eval import statistics, table
from ocplace.eval.api import MethodOutput
from ocplace.eval.harness import redacted, score_scene
from ocplace.experiments import pipeline
from ocplace.methods import registry
from ocplace.methods.contract import LoadContext
from ocplace.methods.policy_method import scene_input
from ocplace.models.inference_settings import Decision, InferenceSettings
from ocplace.sim.dataset.job import scene_dirs
from ocplace.sim.dataset.records import read_scene
from ocplace.vocabulary import TEST_SUBSETS


@pytest.fixture(scope="module")
def object_scenes(smoke_dataset):
    """The smoke test scenes whose instruction names an object, with their ground truth."""
    records = [read_scene(folder) for subset in TEST_SUBSETS for folder in scene_dirs(smoke_dataset, subset)]
    return [record for record in records if record.level != "table"]


def test_an_inference_only_row_trains_nothing_and_its_owners_runs_train_once(tmp_path):
    specs = registry.method_specs()
    assert specs["ours_joint"].train is None and specs["ours_joint"].trained_as == "ours"
    for methods, seeds in ((("ours_joint",), 1), (("ours", "ours_joint"), 2)):
        demo = configs.get("demo")
        experiment = dataclasses.replace(
            demo, evaluation=dataclasses.replace(demo.evaluation, methods=methods, seeds=seeds)
        )
        config = pipeline.PipelineConfig(experiment)
        runs = pipeline.planned_runs(config, pipeline.selected_specs(config, specs))
        nodes = {node.key: node for node in pipeline.task_graph(config, specs, runs, tmp_path, tmp_path, "h")}
        trainings = [key for key in nodes if key.startswith("train ")]
        assert trainings == ["train ours"] + (["train ours~seed1"] if seeds == 2 else [])
        assert ("evaluate ours" in nodes) == ("ours" in methods)
        assert nodes["evaluate ours_joint"].after == ("backbone", "train ours")
        task = nodes["evaluate ours_joint"].make({"backbone": "offline:/b", "train ours": (tmp_path / "run", False)})
        spec, run = task.args[:2]
        assert spec.name == "ours_joint" and run.run_dir == tmp_path / "run"
        assert run.inference == InferenceSettings(Decision("joint"))
        if seeds == 2:
            assert nodes["evaluate ours_joint~seed1"].after == ("backbone", "train ours~seed1")

    from ocplace.errors import EvaluationError
    from ocplace.experiments.evaluation import method_runs

    owners = tmp_path / "out" / "runs" / "ours" / "fraction-1.00"
    owners.mkdir(parents=True)
    [found] = method_runs([specs["ours_joint"]], {}, tmp_path / "out")  # `evaluate --runs-from OUT`
    assert found.run_dir == owners and found.method == "ours_joint"
    with pytest.raises(EvaluationError, match="from the training of ours"):
        method_runs([specs["ours_joint"]], {})


def test_set_reaches_a_rows_inference_settings_and_refuses_what_is_not_one():
    smoke = configs.get("smoke")
    assert set(smoke.inference) == set(registry.inference_defaults()) >= {"ours", "ours_joint", "no_adapter_joint"}
    changed = apply_overrides(smoke, ["inference.ours_joint.decision.top_k=5", "inference.ours.decision.mode=joint"])
    assert changed.inference["ours_joint"].decision == Decision("joint", 5)
    assert changed.inference["ours"].decision.mode == "joint"
    with pytest.raises(ConfigError, match=r"valid keys under 'inference' are ours\.\*, ours_paper\.\*"):
        apply_overrides(smoke, ["inference.grids.decision.mode=joint"])
    with pytest.raises(ConfigError, match="valid keys under 'inference.ours.decision' are mode, top_k"):
        apply_overrides(smoke, ["inference.ours.decision.k=2"])
    with pytest.raises(ConfigError, match="one of argmax, joint"):
        apply_overrides(smoke, ["inference.ours.decision.mode=greedy"])
    with pytest.raises(
        ConfigError, match=r"inference\.ours_joint\.decision\.top_k=0: 0 is out of range: give a number from 1 to 16"
    ):
        apply_overrides(smoke, ["inference.ours_joint.decision.top_k=0"]).validate()
    with pytest.raises(ConfigError, match="inference.grids names no policy row"):
        dataclasses.replace(smoke, inference={**smoke.inference, "grids": InferenceSettings()}).validate()


def test_outcomes_record_every_references_probabilities_and_its_true_token(object_scenes):
    scored = 0
    for record in object_scenes:
        truth = record.tuples
        tokens = len(record.boxes) + 1
        if any(t.token_index >= tokens for t in truth):
            continue
        rows = np.full((len(truth), tokens), 0.1 / tokens)
        for row, item in zip(rows, truth):  # the true token second, another one first
            row[item.token_index] = 0.3
            row[(item.token_index + 1) % tokens] = 0.6
        parsed = tuple((item.reference_name, item.relation) for item in reversed(truth))  # another order
        chosen = tuple(int(np.argmax(row)) for row in rows[::-1])
        output = MethodOutput(None, None, parsed, chosen, "NoFeasiblePlacement: x", probabilities=rows[::-1].tolist())
        outcome = score_scene(record, output)
        assert outcome.true_tokens == tuple(item.token_index for item in reversed(truth))
        assert outcome.true_ranks == (2,) * len(truth) and outcome.chosen_tokens == chosen
        assert outcome.token_names[-1] == "table" and len(outcome.token_names) == tokens
        names = {obj.object_id: obj.name for obj in record.objects}
        for item, column in zip(reversed(truth), outcome.true_tokens):
            assert outcome.token_names[column] == names.get(item.reference_object_id, "table")
        assert np.allclose(outcome.probabilities, rows[::-1], atol=1e-4)
        scored += 1
    assert scored >= 4
    record = object_scenes[0]
    for bad in ([[1.5] * (len(record.boxes) + 1)], [[float("nan")]], "lots"):
        outcome = score_scene(record, MethodOutput(np.zeros(2), None, probabilities=bad))
        assert outcome.failure.startswith("malformed output: ValueError") and outcome.probabilities is None
    unreported = score_scene(record, MethodOutput(np.zeros(2), None, (("mug", "left"),), (0,)))
    assert unreported.probabilities is None and unreported.true_tokens is None


def _entry(key, method, successes, backbone=None, seed=None, description=None):
    scenes = [{"id": f"seen-{k:05d}", "level": "1obj", "success": bool(ok)} for k, ok in enumerate(successes)]
    entry = {
        "key": key,
        "method": method,
        "label": method,
        "fraction": 1.0,
        "description": description or {"run": key},
        "subsets": {
            "seen": {"aggregate": {"overall": {"scenes": len(scenes), "success": np.mean(successes)}}, "scenes": scenes}
        },
    }
    return entry | {name: value for name, value in (("seed", seed), ("backbone_seed", backbone)) if value is not None}


def test_a_row_that_learns_nothing_counts_once_per_backbone_and_rows_are_paired_on_their_runs():
    rng = np.random.default_rng(0)
    base = rng.random(200) < 0.5
    entries = []
    for backbone in (None, 1, 2):
        plain = base ^ (rng.random(200) < 0.1)
        for seed in (None, 1, 2):
            key = "".join(f"~{n}{v}" for n, v in (("seed", seed), ("backbone", backbone)) if v is not None)
            ours = plain | (rng.random(200) < 0.3)  # Ours adds successes to the plain backbone's on every run
            entries.append(_entry("ours" + key, "ours", ours, backbone, seed))
            entries.append(_entry("no_adapter" + key, "no_adapter", plain, backbone, seed, {"backbone": backbone}))
    results = {"settings": {"subsets": ["seen"]}, "evaluations": entries}
    no_adapter = next(e for e in entries if e["key"] == "no_adapter")
    assert len(statistics.repeats(results, no_adapter)) == 3  # nine evaluations, three models
    found = statistics.derive(results)
    assert found["intervals"]["no_adapter"]["seen"]["overall"][3] == 3  # counted once per backbone
    mean, _, high, units, scenes = found["paired"]["no_adapter"]["seen"]["overall"]

    def rate(runs):
        return np.mean([scene["success"] for entry in runs for scene in entry["subsets"]["seen"]["scenes"]])

    ours, plain = rate([e for e in entries if e["method"] == "ours"]), rate(statistics.repeats(results, no_adapter))
    assert mean == pytest.approx(plain - ours) and high < 0 and (units, scenes) == (3, 200)  # the backbones
    assert "ours" not in found["paired"]
    text = table.paired_table(results | {"dataset": {}}, found)
    assert f"**{100 * (plain - ours):+.2f} [" in text  # bold: the interval excludes 0

    joint = _entry("ours_joint", "ours_joint", base, description={"policy": {"decision": {"mode": "joint"}}})
    title = table.table_one({"settings": {"subsets": ["seen"], "threshold": 0.0}, "evaluations": [joint]})
    assert "(always placed; every reference grounded at its argmax, the row of joint inference jointly" in title

    same = {"settings": {"subsets": ["seen"]}, "evaluations": [_entry("ours", "ours", base), _entry("x", "x", base)]}
    cell = statistics.derive(same)["paired"]["x"]["seen"]["overall"]
    assert cell[:3] == [0.0, 0.0, 0.0] and "| +0.00 [+0.0, +0.0] |" in table.paired_table(same, statistics.derive(same))


def test_ours_joint_places_with_ours_run_and_never_lacks_a_placement_it_found(
    trained_run, tiny_backbone_spec, object_scenes
):
    run, _ = trained_run
    specs = registry.method_specs()
    scenes = [redacted(record) for record in object_scenes]
    argmax = specs["ours"].load(LoadContext(run, tiny_backbone_spec, num_samples=32))
    joint = specs["ours_joint"].load(LoadContext(run, tiny_backbone_spec, num_samples=32))
    assert joint.policy.decision == Decision("joint") and argmax.policy.decision == Decision("argmax")
    assert joint.describe()["policy"]["decision"] == {"mode": "joint", "top_k": 5}
    key = jax.random.key(0)
    pairs = list(zip(argmax.run(scenes, key), joint.run(scenes, key)))
    for plain, chosen in pairs:
        assert plain.decision == "argmax" and chosen.decision in ("joint", "joint_fallback")
        assert chosen.probabilities == plain.probabilities  # the same grounding, another decision
        if chosen.decision == "joint":
            assert chosen.failure is None, chosen.failure  # a feasible assignment is a placement
        else:
            assert chosen.grounded == plain.grounded
        if plain.failure is None and len(set(plain.grounded)) == len(plain.grounded):
            assert chosen.grounded == plain.grounded  # the argmax one was consistent and feasible: kept
    assert any(chosen.decision == "joint" for _, chosen in pairs)


def test_a_policy_folder_carries_its_decision_and_an_older_one_keeps_argmax(
    tiny_backbone_spec, smoke_dataset, tmp_path
):
    from ocplace.models.backbone import load_backbone
    from ocplace.models.policy import PlacementPolicy
    from ocplace.models.policy_folder import CONFIG_FILE, export_policy

    policy = PlacementPolicy.from_run(load_backbone(tiny_backbone_spec), None, decision=Decision("joint", 2))
    folder = export_policy(policy, tmp_path / "policy", parser="offline")
    loaded = PlacementPolicy.from_pretrained(folder)
    assert loaded.decision == Decision("joint", 2)
    record = read_scene(scene_dirs(smoke_dataset, "seen")[0])
    placed = loaded.place_many([scene_input(record)], jax.random.key(0))[0]
    assert placed.decision in ("joint", "joint_fallback")
    document = json.loads((folder / CONFIG_FILE).read_text())
    del document["policy"]["decision"]  # as every folder written before the joint decision
    (folder / CONFIG_FILE).write_text(json.dumps(document))
    assert PlacementPolicy.from_pretrained(folder).decision == Decision("argmax")
    document["policy"]["decision"] = {"mode": "joint", "top_k": 0}
    (folder / CONFIG_FILE).write_text(json.dumps(document))
    with pytest.raises(PolicyFolderError, match="policy.decision.top_k: from 1 to 16, got 0"):
        PlacementPolicy.from_pretrained(folder)


def test_the_grounding_report_reads_every_recorded_reference_back(object_scenes, tmp_path):
    from ocplace import serial
    from ocplace.eval import grounding_report
    from ocplace.eval.results import outcome_lines, write_outcomes

    scenes, wanted_right = [], 0
    for index, record in enumerate(object_scenes):
        tokens = len(record.boxes) + 1
        rows = np.full((len(record.tuples), tokens), 0.05)
        for row, item in zip(rows, record.tuples):  # right on even scenes, the next token on odd ones
            row[(item.token_index + index % 2) % tokens] = 0.9
        parsed = tuple((item.reference_name, item.relation) for item in record.tuples)
        chosen = tuple(int(np.argmax(row)) for row in rows)
        outcome = score_scene(record, MethodOutput(np.zeros(2), None, parsed, chosen, probabilities=rows.tolist()))
        scenes.append(serial.to_dict(outcome))
        wanted_right += len(record.tuples) if index % 2 == 0 else 0
    entry = {"key": "ours", "method": "ours", "fraction": 1.0, "subsets": {"seen": {"scenes": scenes}}}
    path = write_outcomes(tmp_path / "outcomes.jsonl.gz", {"evaluations": [entry]})
    rows = grounding_report.references(outcome_lines(path), "ours")
    assert len(rows) == sum(len(record.tuples) for record in object_scenes)
    assert sum(row.right for row in rows) == wanted_right and all(row.rank in (1, 2) for row in rows)
    by_object = grounding_report.accuracy_by_object(rows)
    assert sum(cell["references"] for cell in by_object.values()) == len(rows)
    assert all(cell["rank2"] == 1.0 and cell["rank1"] == cell["chosen"] for cell in by_object.values())
    assert sum(grounding_report.confusions(rows).values()) == len(rows) - wanted_right
    *bins, error = grounding_report.calibration(rows)
    assert [cell["references"] for cell in bins] == [len(rows)] and bins[0]["low"] == 0.9
    assert error["expected_calibration_error"] == pytest.approx(abs(0.9 - wanted_right / len(rows)))


# Slow: the default suite's 15 min budget on 2 cores (docs/performance.md, session 12); the joint row's placement and
# its folder's decision stay in it
@pytest.mark.slow
def test_place_and_reproduce_take_the_decision_and_refuse_what_cannot_run(
    trained_run, tiny_backbone_spec, smoke_dataset, tmp_path, monkeypatch, capsys
):
    from ocplace.cli import main

    run, _ = trained_run
    common = ["place", "--dataset", str(smoke_dataset), "--id", "seen-00001", "--adapters", str(run)]
    common += ["--backbone", tiny_backbone_spec, "--samples", "16"]
    assert main([*common, "--decision", "joint", "--top-k", "2", "--out", str(tmp_path / "p.png")]) in (0, 2)
    assert "decision: joint" in capsys.readouterr().out  # placed, or refused with a reason: decided jointly
    assert main([*common, "--top-k", "9", "--out", str(tmp_path / "q.png")]) == 2
    assert "6,561 assignments" in capsys.readouterr().err and not (tmp_path / "q.png").exists()

    monkeypatch.setattr(pipeline, "run_pipeline", lambda *args, **kwargs: pytest.fail("ran with a refused key"))
    for key, message in (
        ("inference.nope.decision.mode=joint", "valid keys under 'inference' are ours.*"),
        (
            "inference.ours.decision.top_k=0",
            "inference.ours.decision.top_k=0: 0 is out of range: give a number from 1 to 16",
        ),
    ):
        assert main(["reproduce", "--experiment", "smoke", "--out", str(tmp_path / "r"), "--set", key]) == 2
        assert message in capsys.readouterr().err
