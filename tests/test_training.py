"""Adapter training on synthetic cached features: fitting, determinism, checkpoints and resume."""

import argparse
import dataclasses
import json
import re

import numpy as np
import pytest
from safetensors.numpy import load_file
from synthetic_features import synthetic_features

from ocplace.cli import train as train_command
from ocplace.errors import TrainingError
from ocplace.methods.ours.recipe import OursRecipe, default_config, smoke_config
from ocplace.methods.ours.train import train_ours as train
from ocplace.models import trained_adapters
from ocplace.models.adapter_settings import AdapterSettings
from ocplace.models.features import save_features
from ocplace.models.grounding import GroundingModel
from ocplace.paths import OLD_RUN_FILES, RUN_FILE, WEIGHTS_FILE
from ocplace.train import checkpoints
from ocplace.train.batches import batch_indices, subset_indices
from ocplace.train.metrics import MetricsLog, evaluate_features
from ocplace.train.schedule import Schedule, rescheduled

DIM = 32


@pytest.fixture(scope="module")
def features():
    return synthetic_features(48, DIM, seed=0)


@pytest.fixture(scope="module")
def fitted(tmp_path_factory, features):
    run_dir = tmp_path_factory.mktemp("fitted")
    return train(features, run_dir, smoke_config(), val_features=synthetic_features(16, DIM, seed=0), progress=False)


def short_config():
    return rescheduled(smoke_config(), steps=200, checkpoint_every=100)


def adapter_arrays(run_dir):
    return load_file(str(run_dir / WEIGHTS_FILE))


def test_training_fits_a_separable_problem(fitted, features):
    zero_shot = evaluate_features(GroundingModel.zero_shot(DIM, 100.0), features)
    assert zero_shot.tuple_accuracy < 0.6  # text and image prototypes are unrelated
    records = MetricsLog(fitted.run_dir / "metrics.jsonl").records()
    assert [r["step"] for r in records] == list(range(50, 301, 50))
    assert records[-1]["loss"] < records[0]["loss"] / 10
    assert fitted.train_accuracy.tuple_accuracy == 1.0 and fitted.train_accuracy.scene_accuracy == 1.0
    assert records[-1]["train_tuple_accuracy"] == 1.0 and "val_scene_accuracy" in records[-1]


def test_adapters_file_round_trip(fitted, features):
    trained = trained_adapters.load_adapters(fitted.run_dir)
    assert trained.steps == 300 and trained.features_key == features.info.key
    assert trained.model.config == fitted.model.config and trained.model.logit_scale == 100.0
    np.testing.assert_array_equal(
        trained.model.logits(features.text, features.visual, features.visual_mask),
        fitted.model.logits(features.text, features.visual, features.visual_mask),
    )


def test_checkpoint_round_trip(fitted):
    saved = checkpoints.list_checkpoints(fitted.run_dir)
    assert [p.name for p in saved] == ["step_000000200.safetensors", "step_000000300.safetensors"]  # keep 2
    import jax

    state, step, metadata = checkpoints.load_checkpoint(saved[-1], _state_template(fitted))
    assert step == 300 and "run" in metadata
    for a, b in zip(jax.tree_util.tree_leaves(state[0]), jax.tree_util.tree_leaves(fitted.model.params)):
        np.testing.assert_array_equal(a, b)
    with pytest.raises(TrainingError, match="does not match"):
        checkpoints.load_checkpoint(saved[-1], (fitted.model.params, None))


def _state_template(result):
    from ocplace.methods.ours.train import init_state
    from ocplace.train import optim

    return init_state(result.model.config, optim.make(smoke_config().schedule), seed=123)


def test_same_seed_same_weights_and_resume_equals_uninterrupted(tmp_path, features):
    config = short_config()
    train(features, tmp_path / "a", config, progress=False)
    train(features, tmp_path / "b", config, progress=False)

    def crash_after_first_checkpoint(record):
        if record["step"] == 100:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        train(features, tmp_path / "c", config, progress=False, callback=crash_after_first_checkpoint)
    assert not (tmp_path / "c" / WEIGHTS_FILE).exists()
    train(features, tmp_path / "c", config, progress=False)
    train(features, tmp_path / "d", config, seed=1, progress=False)

    a, b, c, d = (adapter_arrays(tmp_path / name) for name in "abcd")
    for key in a:
        np.testing.assert_array_equal(a[key], b[key])
        np.testing.assert_array_equal(a[key], c[key])
    assert any(not np.array_equal(a[key], d[key]) for key in a)
    steps = [r["step"] for r in MetricsLog(tmp_path / "c" / "metrics.jsonl").records()]
    assert steps == [50, 100, 150, 200]  # resumed at 100, nothing repeated


def test_a_run_directory_refuses_other_settings(tmp_path, features):
    config = dataclasses.replace(rescheduled(short_config(), steps=50, checkpoint_every=50), eval_every=50)
    train(features, tmp_path, config, progress=False)
    with pytest.raises(TrainingError, match="holds another run"):
        train(features, tmp_path, rescheduled(config, learning_rate=1e-3), progress=False)
    with pytest.raises(TrainingError, match="holds another run"):
        train(features, tmp_path, config, seed=1, progress=False)


@pytest.mark.parametrize("old_name", OLD_RUN_FILES)
def test_a_run_with_old_file_names_is_refused_not_mixed(fitted, tmp_path, old_name):
    """A run an older version wrote is neither resumed nor loaded, even beside a current weights file."""
    run = tmp_path / "old"
    run.mkdir()
    (run / old_name).write_text("{}")
    (run / WEIGHTS_FILE).write_bytes((fitted.run_dir / WEIGHTS_FILE).read_bytes())
    with pytest.raises(TrainingError, match=f"older ocplace \\(it holds {re.escape(old_name)};.*delete it"):
        checkpoints.claim_run_dir(run, {"run": "new"})
    with pytest.raises(TrainingError, match="older ocplace.*train them with `ocplace train`"):
        trained_adapters.load_adapters(run)
    assert not (run / RUN_FILE).exists()


def test_a_run_without_weights_says_how_to_train(tmp_path):
    with pytest.raises(TrainingError, match="no trained adapters at .*weights.safetensors; train them"):
        trained_adapters.load_adapters(tmp_path)


def test_adam_matches_optax_adam():
    import jax
    import jax.numpy as jnp
    import optax

    from ocplace.train import optim

    schedule = optax.warmup_cosine_decay_schedule(0.0, 1e-2, 20, 100, 0.0)
    target = jnp.asarray(np.random.default_rng(0).normal(size=(16, 8)), jnp.float32)

    def run(optimizer):
        params = {"w": jnp.zeros((16, 8)), "b": jnp.ones((8,))}
        state = optimizer.init(params)

        def step(carry, _):
            params, state = carry
            grads = jax.grad(lambda p: jnp.sum((p["w"] + p["b"] - target) ** 2))(params)
            updates, state = optimizer.update(grads, state, params)
            return (optax.apply_updates(params, updates), state), None

        return jax.jit(lambda c: jax.lax.scan(step, c, None, length=100))((params, state))[0][0]

    ours, reference = run(optim.adam(schedule)), run(optax.adam(schedule))
    for key in ours:
        np.testing.assert_allclose(ours[key], reference[key], rtol=1e-4, atol=1e-5)  # float32 rounding
    assert not np.allclose(ours["w"], 0.0)


def test_weight_decay_is_adamw_decoupled_decay():
    import jax.numpy as jnp
    import optax

    from ocplace.train import optim

    params = {"w": jnp.full((4, 3), 2.0)}
    zero = {"w": jnp.zeros((4, 3))}
    plain, decayed = optim.adam(0.1), optim.adam(0.1, weight_decay=0.5)
    assert np.all(plain.update(zero, plain.init(params), params)[0]["w"] == 0.0)
    updates, _ = decayed.update(zero, decayed.init(params), params)
    np.testing.assert_allclose(updates["w"], -0.1 * 0.5 * 2.0)  # what optax.adamw's decay term gives
    reference, _ = optax.adamw(0.1, weight_decay=0.5).update(
        zero, optax.adamw(0.1, weight_decay=0.5).init(params), params
    )
    np.testing.assert_allclose(updates["w"], reference["w"], rtol=1e-6)


def test_the_anchor_keeps_the_adapted_features_near_the_backbones(tmp_path, features):
    from ocplace.models.adapters import apply_adapters

    def drift_and_accuracy(anchor: float) -> tuple[float, float]:
        config = dataclasses.replace(short_config(), anchor=anchor)
        result = train(features, tmp_path / f"anchor-{anchor}", config, progress=False)
        visual, _ = apply_adapters(result.model.config, result.model.params, features.visual, features.text)
        squared = np.sum((np.asarray(visual) - features.visual) ** 2, axis=-1)
        return float(np.mean(squared[features.visual_mask])), result.train_accuracy.tuple_accuracy

    free, _ = drift_and_accuracy(0.0)
    pulled, accuracy = drift_and_accuracy(100.0)
    assert pulled < free / 2
    assert accuracy > 0.5  # it still learns the task


def test_fraction_subsets_are_seeded_and_nested():
    quarter, half = subset_indices(100, 0.25, 0), subset_indices(100, 0.5, 0)
    assert len(quarter) == 25 and len(half) == 50
    assert set(quarter) <= set(half)
    np.testing.assert_array_equal(quarter, subset_indices(100, 0.25, 0))
    assert not np.array_equal(quarter, subset_indices(100, 0.25, 1))


def test_batch_indices_shuffle_each_epoch_and_depend_only_on_the_step():
    indices = batch_indices(10, seed=0, start_step=0, num_steps=30, batch_size=1)[:, 0]
    for epoch in range(3):
        assert sorted(indices[10 * epoch : 10 * epoch + 10]) == list(range(10))
    assert not np.array_equal(indices[:10], indices[10:20])
    np.testing.assert_array_equal(batch_indices(10, 0, 7, 13, 1)[:, 0], indices[7:20])
    assert batch_indices(10, 0, 0, 5, 2).shape == (5, 2)


def test_train_command(tmp_path, features):
    path = save_features(features, tmp_path / "features.safetensors")
    run = tmp_path / "run"
    parser = argparse.ArgumentParser()
    train_command.register(parser.add_subparsers())
    args = parser.parse_args(
        [
            "train",
            "--features",
            str(path),
            "--out",
            str(run),
            "--smoke",
            "--steps",
            "100",
            "--fraction",
            "0.5",
            "--cpus",
            "0",
        ]
    )  # 0: do not pin the test process
    assert args.func(args) == 0
    meta = json.loads((run / RUN_FILE).read_text())
    assert meta["train_scenes"] == 24 and meta["train_config"]["recipe"]["schedule"]["steps"] == 100
    assert trained_adapters.load_adapters(run).steps == 100


def test_train_command_gives_the_bits_of_a_reproduce_training_task(tmp_path, features, monkeypatch):
    """`ocplace train` starts JAX through the pin of `reproduce`'s tasks (`runtime.width.pin_jax_width`, seen by
    the compilation cache it sets for that width) at the width `reproduce` declares for its trainings
    (`TaskCpus.train`): the same recipe gives the same weights."""
    import os
    import subprocess
    import sys

    from ocplace.experiments.experiment import TaskCpus
    from ocplace.runtime import ExecutorConfig, Task, map_tasks, open_executor
    from ocplace.runtime.width import compiled_folder

    monkeypatch.setenv("OCPLACE_CACHE", str(tmp_path / "cache"))  # the compilation cache of both
    path = save_features(features, tmp_path / "features.safetensors")
    command = ["train", "--features", str(path), "--out", str(tmp_path / "command"), "--smoke", "--steps", "100"]
    subprocess.run([sys.executable, "-m", "ocplace.cli", *command], check=True, capture_output=True)
    assert list(compiled_folder(min(TaskCpus().train, len(os.sched_getaffinity(0)))).glob("*-cache"))
    config = rescheduled(smoke_config(), steps=100)
    task = Task(train, (features, tmp_path / "task", config), cpus=TaskCpus().train, pinned=True)
    with open_executor(ExecutorConfig(workers=1)) as executor:
        next(map_tasks(executor, [task]))
    by_command, by_task = adapter_arrays(tmp_path / "command"), adapter_arrays(tmp_path / "task")
    assert by_command.keys() == by_task.keys()
    assert all(np.array_equal(by_command[name], by_task[name]) for name in by_command)


def test_train_method_trains_a_row_through_its_spec_as_reproduce_does(
    trained_run, smoke_dataset, tiny_backbone_spec, tmp_path, monkeypatch, capsys
):
    """`ocplace train --method ours` gives the weights of the same row trained through its `MethodSpec` with the
    same recipe, fraction and seed (the `trained_run` fixture: what a `reproduce` task does, in this process)."""
    from ocplace.cli import main

    run_dir, features = trained_run
    monkeypatch.setenv("OCPLACE_CACHE", str(features[0].parents[1]))  # its cache: the same features, not made again
    common = ["--dataset", str(smoke_dataset), "--backbone", tiny_backbone_spec, "--experiment", "smoke", "--cpus", "0"]
    command = ["train", "--method", "ours", *common, "--fraction", "0.5", "--seed", "3", "--out", str(tmp_path / "run")]
    assert main(command) == 0
    assert "Ours trained (smoke recipe, fraction 0.5, seed 3)" in capsys.readouterr().out
    by_command, by_spec = adapter_arrays(tmp_path / "run"), adapter_arrays(run_dir)
    assert by_command.keys() == by_spec.keys()
    assert all(np.array_equal(by_command[name], by_spec[name]) for name in by_command)
    weights = (tmp_path / "run" / WEIGHTS_FILE).read_bytes()
    assert main(command) == 0  # the same context again: recorded as done (`train_once`, as reproduce), not touched
    assert "Ours done before (smoke recipe" in capsys.readouterr().out
    assert (tmp_path / "run" / WEIGHTS_FILE).read_bytes() == weights
    refusals = {
        "no_adapter": "no_adapter learns nothing",
        "nothing": "unknown method 'nothing'; registered: ours, ",
    }
    for method, message in refusals.items():
        assert main(["train", "--method", method, *common, "--out", str(tmp_path / method)]) == 2
        assert message in capsys.readouterr().err
    assert main(["train", "--method", "ours", *common, "--steps", "5", "--out", str(tmp_path / "steps")]) == 2
    assert "change it with --set recipes.NAME.FIELD=VALUE" in capsys.readouterr().err
    assert not (tmp_path / "steps").exists()
    (tmp_path / "a file").write_text("kept")
    assert main(["train", "--method", "ours", *common, "--out", str(tmp_path / "a file")]) == 2
    assert "it is a file, not a folder" in capsys.readouterr().err and (tmp_path / "a file").read_text() == "kept"
    missing = ["--dataset", str(tmp_path / "no dataset"), "--backbone", tiny_backbone_spec, "--cpus", "0"]
    assert main(["train", "--method", "ours", *missing, "--out", str(tmp_path / "none")]) == 2
    assert "has no manifest.json" in capsys.readouterr().err and not (tmp_path / "none").exists()


@pytest.mark.parametrize("content", ['{"train_config": {"st', "", "[]"])
def test_a_damaged_run_file_is_typed_when_the_run_resumes_or_loads(tmp_path, features, capsys, content):
    from ocplace.cli import main
    from ocplace.models.baselines.trained_run import load_run

    path = save_features(features, tmp_path / "features.safetensors")
    run = tmp_path / "run"
    command = ["train", "--features", str(path), "--out", str(run), "--smoke", "--steps", "50", "--cpus", "0"]
    assert main(command) == 0
    (run / RUN_FILE).write_text(content)
    capsys.readouterr()
    assert main(command) == 2
    message = f"{run / RUN_FILE} is truncated or damaged (not a JSON object), so the run cannot be checked or resumed"
    assert capsys.readouterr().err.startswith(f"ocplace train: error: {message}")
    with pytest.raises(TrainingError, match=re.escape(f"delete {run} to train it again")):
        load_run(run, "grids")


def _train_args(*options):
    parser = argparse.ArgumentParser()
    train_command.register(parser.add_subparsers())
    return parser.parse_args(["train", "--features", "f.safetensors", "--out", "run", *options])


def test_train_flags_mirror_every_config_field_and_keep_the_old_names():
    assert train_command.train_config_from_args(_train_args()) == default_config()
    assert train_command.train_config_from_args(_train_args("--smoke")) == smoke_config()
    assert train_command.train_config_from_args(_train_args("--paper-adapters")) == OursRecipe()
    every_field = [
        *("--steps", "7", "--batch-size", "2", "--lr", "0.5", "--warmup-steps", "3", "--seed", "4"),
        *("--fraction", "0.25", "--subset-seed", "5", "--reduction", "8", "--residual-ratio", "0.3"),
        *("--logit-scale", "50", "--chunk-steps", "10", "--eval-every", "20", "--checkpoint-every", "30"),
        *("--keep-checkpoints", "3", "--text-ratio", "0.1", "--normalise", "--weight-decay", "0.01"),
        *("--anchor", "2"),
    ]
    args = _train_args("--smoke", *every_field)
    assert train_command.train_config_from_args(args) == OursRecipe(
        AdapterSettings(reduction=8, residual_ratio=0.3, text_ratio=0.1, normalise=True),
        Schedule(
            steps=7,
            batch_size=2,
            learning_rate=0.5,
            warmup_steps=3,
            chunk_steps=10,
            checkpoint_every=30,
            keep_checkpoints=3,
            weight_decay=0.01,
        ),
        anchor=2.0,
        logit_scale=50.0,
        eval_every=20,
        subset_seed=5,
    )
    assert train_command.run_keys(args) == (4, 0.25)  # the run's, apart from its recipe
    assert train_command.train_config_from_args(_train_args("--learning-rate", "0.25")).schedule.learning_rate == 0.25
