"""Weights integrity (docs/reliability.md#weights): each saved weight file is hashed, checked on load, refused typed.

Each kind of weight file is written by its real saver with weights of the model's shapes, then damaged
(a flipped byte in the tensor data, a truncated file, a NaN tensor under a valid hash) and loaded
by its real loader. Also: a NaN grounding probability never passes the threshold, and a torn last
line of metrics.jsonl does not stop a run from resuming.
"""

import dataclasses
import logging
import re
import shutil
from types import SimpleNamespace

import jax
import numpy as np
import pytest
from safetensors import safe_open
from safetensors.numpy import save_file
from synthetic_features import synthetic_features

from ocplace import serial
from ocplace.errors import BackboneError, GroundingUncertain, TrainingError, WeightsError
from ocplace.methods.cliport import model as cliport
from ocplace.methods.cliport import recipe as cliport_config
from ocplace.methods.grids import model as grids
from ocplace.methods.grids import recipe as grid_config
from ocplace.methods.no_llm import train as no_llm
from ocplace.methods.no_llm.model import NoLlmConfig, NoLlmModel
from ocplace.methods.no_llm.model import init_params as init_no_llm
from ocplace.methods.no_llm.model import load_model as load_no_llm
from ocplace.methods.ours.recipe import smoke_config
from ocplace.methods.ours.train import init_state
from ocplace.methods.ours.train import train_ours as train
from ocplace.models import offline_backbone as ob
from ocplace.models import offline_config, trained_adapters, weights_file
from ocplace.models.adapters import AdapterConfig, init_adapters
from ocplace.models.backbone import PromptConfig
from ocplace.models.grounding import GroundingModel
from ocplace.models.policy import PlacementPolicy, PreparedScene
from ocplace.paths import WEIGHTS_FILE
from ocplace.train import baseline_runs, checkpoints, optim
from ocplace.train.metrics import MetricsLog
from ocplace.train.schedule import rescheduled

DIM = 16
KEY = jax.random.key(0)


# ----------------------------------------------------------------------------- one writer per kind
# Each returns (the weight file, a loader of it through ocplace's own code, the parameters written).


def _random_like(init):
    """Random weights shaped like `init()`'s, drawn in NumPy: eager Flax init of CLIPort's U-Net alone
    takes over 20 s on a busy CPU, and the values do not matter here."""
    rng = np.random.default_rng(0)
    return jax.tree_util.tree_map(lambda leaf: rng.standard_normal(leaf.shape).astype(leaf.dtype), jax.eval_shape(init))


def _checkpoint(run_dir):
    template = jax.eval_shape(lambda: init_state(AdapterConfig(dim=DIM), optim.make(smoke_config().schedule), seed=0))
    state = _random_like(lambda: template)
    path = checkpoints.save_checkpoint(run_dir, 100, state, {"run": "test"}, keep=2)
    return path, lambda: checkpoints.load_checkpoint(path, template)[0], state


def _adapters(run_dir):
    config = AdapterConfig(dim=DIM)
    params = _random_like(lambda: init_adapters(config, KEY))
    path = run_dir / WEIGHTS_FILE
    trained_adapters.save_adapters(
        path,
        params,
        config,
        30.0,
        backbone_fingerprint="f",
        prompt=PromptConfig(),
        features_key="k",
        steps=1,
        train_config_json="{}",
    )
    return path, lambda: trained_adapters.load_adapters(run_dir).model.params, params


def _grids(run_dir):
    config = grid_config.smoke_grid_config()
    checkpoints.claim_run_dir(run_dir, {"grid": serial.to_dict(config)})
    params = _random_like(lambda: grids.init_grids(config, DIM, KEY))
    path = baseline_runs.save_weights(run_dir, params, {"run": "test"})
    return path, lambda: grids.load_params(run_dir)[0], params


def _cliport(run_dir):
    config = cliport_config.smoke_config()
    checkpoints.claim_run_dir(run_dir, {"network": serial.to_dict(config), "dim": DIM})
    params = _random_like(lambda: cliport.init_network(config, DIM, KEY))
    path = baseline_runs.save_weights(run_dir, params, {"run": "test"})
    return path, lambda: cliport.load_params(run_dir)[0], params


def _no_llm(run_dir):
    config = NoLlmConfig(dim=DIM, hidden=8)
    params = _random_like(lambda: init_no_llm(config, KEY))
    path = run_dir / WEIGHTS_FILE
    no_llm.save_model(
        path,
        NoLlmModel(config, params, 30.0),
        backbone_fingerprint="f",
        train_config={"recipe": {}, "seed": 0, "fraction": 1.0},
    )
    return path, lambda: load_no_llm(run_dir).model.params, params


@pytest.fixture(scope="module")
def saved_backbone(tmp_path_factory):
    config = offline_config.smoke_config()
    params = ob.init_params(config, KEY)
    directory = ob.save_backbone(
        tmp_path_factory.mktemp("backbone") / "backbone",
        config,
        params,
        ob.FrozenTextTower.load(config.text_max_length).digest,
    )
    return directory, params


@pytest.fixture
def no_pretrain_backbone(saved_backbone):
    """The offline-backbone directory a no_pretrain run saves as its `backbone/` (its adapters are `_adapters`)."""

    def write(run_dir):
        directory = shutil.copytree(saved_backbone[0], run_dir / "backbone")
        return directory / WEIGHTS_FILE, lambda: ob.load_saved_backbone(directory).params, saved_backbone[1]

    return write


HASHED = {"checkpoint": _checkpoint, "adapters": _adapters, "grids": _grids, "cliport": _cliport, "no_llm": _no_llm}
KINDS = [*HASHED, "no_pretrain_backbone"]


@pytest.fixture(params=KINDS)
def kind(request, tmp_path):
    write = HASHED.get(request.param) or request.getfixturevalue(request.param)
    return request.param, *write(tmp_path / "run")


def _assert_same_tree(loaded, saved):
    loaded, saved = jax.tree_util.tree_leaves(loaded), jax.tree_util.tree_leaves(saved)
    assert len(loaded) == len(saved)
    for a, b in zip(loaded, saved):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def _data_offset(path) -> int:
    """Where the tensor bytes start: after the 8-byte header length and the JSON header."""
    return 8 + int.from_bytes(path.read_bytes()[:8], "little")


# ----------------------------------------------------------------------------- the promises


def test_an_intact_file_round_trips(kind, caplog):
    _, _, load, saved = kind
    with caplog.at_level(logging.WARNING):
        _assert_same_tree(load(), saved)
    assert not caplog.records  # hashed, so no "older ocplace" warning


def test_a_flipped_byte_in_the_tensor_data_is_refused(kind):
    name, path, load, _ = kind
    data = bytearray(path.read_bytes())
    offset = _data_offset(path)
    data[(offset + len(data)) // 2] ^= 0x01
    path.write_bytes(bytes(data))
    # the offline backbone's own hash is its fingerprint, checked as before (a BackboneError)
    error = BackboneError if name == "no_pretrain_backbone" else WeightsError
    match = "fingerprint" if name == "no_pretrain_backbone" else "does not match its content hash"
    with pytest.raises(error, match=match) as caught:
        load()
    assert str(path) in str(caught.value) and "delete" in str(caught.value)


def test_a_truncated_file_is_refused(kind):
    _, path, load, _ = kind
    data = path.read_bytes()
    path.write_bytes(data[: (_data_offset(path) + len(data)) // 2])
    with pytest.raises(WeightsError, match=re.escape(str(path)) + ".*truncated or damaged") as caught:
        load()
    assert "delete" in str(caught.value)


def test_a_nan_tensor_is_refused_even_under_a_valid_hash(kind):
    name, path, load, _ = kind
    with safe_open(str(path), framework="numpy") as handle:
        metadata = handle.metadata()
        tensors = {key: handle.get_tensor(key) for key in handle.keys()}
    target = next(key for key in sorted(tensors) if tensors[key].dtype == np.float32)
    tensors[target] = np.full_like(tensors[target], np.nan)
    if name == "no_pretrain_backbone":
        save_file(tensors, str(path), metadata=metadata)
    else:
        metadata.pop(weights_file.HASH_KEY)
        weights_file.save_weights(path, tensors, metadata)  # re-hashed: only the NaN check can catch it
    with pytest.raises(WeightsError, match=re.escape(str(path)) + ".*NaN or inf.*" + re.escape(target)):
        load()


@pytest.mark.parametrize("name", list(HASHED))
def test_a_file_from_before_the_hash_loads_with_a_warning(name, tmp_path, caplog):
    path, load, saved = HASHED[name](tmp_path / "run")
    with safe_open(str(path), framework="numpy") as handle:
        metadata = handle.metadata()
        tensors = {key: handle.get_tensor(key) for key in handle.keys()}
    metadata.pop(weights_file.HASH_KEY)
    save_file(tensors, str(path), metadata=metadata)  # what the older savers wrote
    with caplog.at_level(logging.WARNING, logger="ocplace.models.weights_file"):
        _assert_same_tree(load(), saved)
    assert str(path) in caplog.text and "no content hash" in caplog.text


def test_the_hash_covers_the_metadata(tmp_path):
    path = weights_file.save_weights(tmp_path / "w.safetensors", {"a": np.ones(3, np.float32)}, {"scale": "30.0"})
    with safe_open(str(path), framework="numpy") as handle:
        metadata = handle.metadata()
    save_file({"a": np.ones(3, np.float32)}, str(path), metadata={**metadata, "scale": "38.0"})
    with pytest.raises(WeightsError, match="content hash"):
        weights_file.load_weights(path, "rebuild it")


def test_the_same_weights_give_the_same_bytes(tmp_path):
    tensors = {"b": np.ones((2, 3), np.float32), "a": np.arange(4, dtype=np.int32)}
    metadata = {key: str(value) for value, key in enumerate("zyxwvutsrq")}  # hash-map order varies per call
    first = weights_file.save_weights(tmp_path / "1.safetensors", tensors, metadata).read_bytes()
    assert all(
        weights_file.save_weights(tmp_path / "2.safetensors", tensors, metadata).read_bytes() == first for _ in range(5)
    )


# ----------------------------------------------------------------------------- grounding and resume


def test_a_nan_grounding_probability_never_passes_the_threshold():
    model = GroundingModel(
        AdapterConfig(dim=DIM),
        jax.tree_util.tree_map(lambda a: np.full_like(a, np.nan), init_adapters(AdapterConfig(dim=DIM), KEY)),
        30.0,
    )
    probabilities = model.probabilities(np.ones((1, DIM), np.float32), np.eye(3, DIM, dtype=np.float32))
    assert np.isnan(probabilities).all()  # real jitted adapters with NaN weights
    boxes = np.array([[0, 0, 4, 4], [5, 5, 9, 9]], np.int32)
    scene = PreparedScene(
        "s",
        "put it left of the cup",
        np.zeros((10, 10, 3), np.uint8),
        None,
        boxes,
        np.zeros((2, 2, 2)),
        np.zeros((2, 8, 8, 3), np.uint8),
        np.zeros((8, 8, 3), np.uint8),
        np.zeros(2),
        (),
    )
    policy = PlacementPolicy(backbone=None, grounding=model, prompt=PromptConfig(), parser=None, threshold=0.0)
    references = policy.decide(scene, [SimpleNamespace(reference="cup", relation="left")], probabilities)
    assert np.isnan(references[0].probability)
    with pytest.raises(GroundingUncertain, match="cup"):
        policy.check_confidence(scene, references)


def test_a_torn_last_metrics_line_is_dropped_and_the_run_resumes(tmp_path, caplog):
    features = synthetic_features(24, DIM, seed=0)
    config = dataclasses.replace(rescheduled(smoke_config(), steps=100, checkpoint_every=50), eval_every=50)

    def crash_at_50(record):
        if record["step"] == 50:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        train(features, tmp_path / "torn", config, progress=False, callback=crash_at_50)
    metrics = tmp_path / "torn" / "metrics.jsonl"
    with metrics.open("a") as handle:
        handle.write('{"loss": 0.12, "st')  # the crash hit mid-append
    with caplog.at_level(logging.WARNING, logger="ocplace.train.metrics"):
        train(features, tmp_path / "torn", config, progress=False)
    assert "torn last line" in caplog.text
    assert [r["step"] for r in MetricsLog(metrics).records()] == [50, 100]
    train(features, tmp_path / "whole", config, progress=False)
    _assert_same_tree(
        trained_adapters.load_adapters(tmp_path / "torn").model.params,
        trained_adapters.load_adapters(tmp_path / "whole").model.params,
    )


def test_a_bad_metrics_line_before_the_last_is_refused(tmp_path):
    path = tmp_path / "metrics.jsonl"
    path.write_text('{"step": 1}\n{"st\n{"step": 2}\n')
    with pytest.raises(TrainingError, match="line 2 is not JSON"):
        MetricsLog(path).records()
