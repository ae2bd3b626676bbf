"""Ablations of Table I: Ours w/o LLM (`no_llm`) and Ours w/o CLIP pre-train, on the smoke benchmark."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from lazy import Lazy
from safetensors.numpy import load_file

from ocplace.configs import smoke
from ocplace.eval.harness import redacted
from ocplace.methods.contract import LoadContext, TrainContext
from ocplace.methods.no_llm import model as no_llm
from ocplace.paths import RUN_FILE, WEIGHTS_FILE
from ocplace.sim.dataset.job import scene_dirs
from ocplace.sim.dataset.records import read_scene
from ocplace.sim.relations import RELATION_NAMES
from ocplace.sim.workspace import DEFAULT_TABLE
from ocplace.train.metrics import MetricsLog

MIDDLE = RELATION_NAMES.index("middle")
RECIPES = smoke.get_config().recipes


@pytest.fixture(scope="module")
def isolated_cache(smoke_dataset, tmp_path_factory):
    """Feature and crop caches in a temporary directory (the library stays where the session built it)."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("OCPLACE_CACHE", str(tmp_path_factory.mktemp("ablations_cache")))
        yield


@pytest.fixture(scope="module")
def specs():
    from ocplace.methods.no_llm import method as no_llm
    from ocplace.methods.no_pretrain import method as no_pretrain

    return {spec.name: spec for spec in (no_llm.SPEC, no_pretrain.SPEC)}


METHOD_NAMES = ["no_llm", "no_pretrain"]


@pytest.fixture(scope="module")
def runs(isolated_cache, smoke_rows):
    """Each method trained at smoke scale when first asked for: {name: run directory} (shared with
    test_registered_rows.py)."""
    return smoke_rows


@pytest.fixture(scope="module")
def scenes(smoke_dataset):
    return [redacted(read_scene(d)) for d in scene_dirs(smoke_dataset, "seen")]


@pytest.fixture(scope="module")
def methods(runs, specs, tiny_backbone_spec):
    return Lazy(lambda name: specs[name].load(LoadContext(runs[name], tiny_backbone_spec, num_samples=32)))


# ----------------------------------------------------------------------------- no_llm pieces


def test_select_references_takes_top_l_and_never_a_padded_token():
    rng = np.random.default_rng(0)
    mask = np.array([[True] * 6, [True, True, False, False, False, False], [True] + [False] * 5])
    logits = jnp.where(mask, jnp.asarray(rng.normal(size=(3, 6)), jnp.float32), -jnp.inf)
    select = jax.jit(no_llm.select_references)
    indices, chosen = select(logits, jnp.array([2, 2, 2]))
    indices, chosen = np.asarray(indices), np.asarray(chosen)
    assert indices.shape == (3, 2) and chosen.tolist() == [[True, True], [True, True], [True, False]]
    assert set(indices[0]) == set(np.argsort(-np.asarray(logits[0]))[:2])
    assert all(mask[row, indices[row][chosen[row]]].all() for row in range(3))
    _, one = select(logits, jnp.array([1, 1, 1]))
    assert np.asarray(one).tolist() == [[True, False]] * 3


def test_relation_head_shapes_and_middle_only_for_the_table():
    config = no_llm.NoLlmConfig(dim=16, hidden=8)
    params = no_llm.init_params(config, jax.random.key(0))
    rng = np.random.default_rng(1)
    visual = jnp.asarray(rng.normal(size=(2, 6, 16)), jnp.float32)
    mask = jnp.array([[True] * 4 + [False] * 2, [True] * 6])

    @jax.jit
    def relation_logits(params, visual, mask):
        visual_star, sentence_star = no_llm.adapted_tokens(config, params, visual, jnp.ones((2, 16)))
        return no_llm.relation_logits(config, params, visual_star, sentence_star, mask)

    logits = np.asarray(relation_logits(params, visual, mask))
    assert logits.shape == (2, 6, len(RELATION_NAMES))
    assert np.isfinite(logits[0, 3]).all() and np.isfinite(logits[1, 5]).all()  # the table tokens
    assert np.isneginf(logits[0, :3, MIDDLE]).all() and np.isneginf(logits[1, :5, MIDDLE]).all()
    model = no_llm.NoLlmModel(config, params, 10.0)
    prediction = model.predict(visual, mask, np.ones((2, 16)), np.array([1, 2]))
    assert prediction.references.shape == prediction.relations.shape == (2, 2)
    assert prediction.reference_mask.tolist() == [[True, False], [True, True]]
    np.testing.assert_allclose(prediction.token_probabilities.sum(-1), 1.0, rtol=1e-5)
    assert prediction.token_probabilities[0, 4:].max() == 0.0


def test_reference_loss_is_ours_with_the_sentence_for_every_tuple():
    config = no_llm.NoLlmConfig(dim=8, hidden=4)
    params = no_llm.init_params(config, jax.random.key(2))
    rng = np.random.default_rng(3)
    batch = {
        "visual": jnp.asarray(rng.normal(size=(3, 6, 8)), jnp.float32),
        "visual_mask": jnp.ones((3, 6), bool),
        "sentence": jnp.asarray(rng.normal(size=(3, 8)), jnp.float32),
        "targets": jnp.array([[0, 0], [1, 2], [5, 0]]),
        "target_mask": jnp.array([[1, 0], [1, 1], [1, 0]], bool),
        "relations": jnp.array([[0, 0], [1, 2], [4, 0]]),
    }
    reference, relation = jax.jit(no_llm.loss_terms, static_argnums=0)(config, params, batch, 10.0)

    @jax.jit
    def log_probabilities(params, batch):
        visual_star, sentence_star = no_llm.adapted_tokens(config, params, batch["visual"], batch["sentence"])
        return jax.nn.log_softmax(no_llm.token_logits(visual_star, sentence_star, batch["visual_mask"], 10.0))

    log_p = np.asarray(log_probabilities(params, batch))
    expected = -np.mean([log_p[0, 0], log_p[1, 1], log_p[1, 2], log_p[2, 5]])
    np.testing.assert_allclose(float(reference), expected, rtol=1e-5)
    assert np.isfinite(float(relation)) and float(relation) > 0


def synthetic_scenes(num_scenes: int, dim: int, seed: int) -> dict:
    """One reference per scene; the sentence is its visual token plus an embedding of its relation."""
    rng = np.random.default_rng(seed)
    relation_codes = rng.normal(size=(len(RELATION_NAMES), dim))
    visual = rng.normal(size=(num_scenes, 6, dim))
    num_tokens = rng.integers(2, 7, size=num_scenes)
    mask = np.arange(6) < num_tokens[:, None]
    visual[~mask] = 0.0
    targets = np.stack([rng.integers(n) for n in num_tokens])
    is_table = targets == num_tokens - 1
    relations = np.where(
        is_table, rng.integers(9, size=num_scenes), rng.choice([i for i in range(9) if i != MIDDLE], size=num_scenes)
    )
    sentence = visual[np.arange(num_scenes), targets] + relation_codes[relations]
    pad = np.zeros((num_scenes, 1), np.int32)
    return {
        "visual": visual.astype(np.float32),
        "visual_mask": mask,
        "sentence": sentence.astype(np.float32),
        "targets": np.concatenate([targets[:, None], pad], 1).astype(np.int32),
        "target_mask": np.concatenate([np.ones_like(pad, bool), pad.astype(bool)], 1),
        "relations": np.concatenate([relations[:, None], pad], 1).astype(np.int32),
    }


def test_no_llm_learns_references_and_relations_when_the_sentence_holds_them(tmp_path):
    import dataclasses

    from ocplace.methods.no_llm.train import train_on_arrays
    from ocplace.train.schedule import rescheduled

    arrays = synthetic_scenes(96, 16, seed=0)
    config = rescheduled(RECIPES["no_llm"], steps=400, chunk_steps=200, checkpoint_every=200)
    config = dataclasses.replace(config, hidden=64)
    model = train_on_arrays(
        arrays, tmp_path / "run", config, 10.0, {"synthetic": True}, progress=False, backbone_fingerprint="synthetic"
    )
    prediction = model.predict(arrays["visual"], arrays["visual_mask"], arrays["sentence"], np.ones(96, np.int32))
    assert np.mean(prediction.references[:, 0] == arrays["targets"][:, 0]) >= 0.95
    assert np.mean(prediction.relations[:, 0] == arrays["relations"][:, 0]) >= 0.9


# ----------------------------------------------------------------------------- training


@pytest.mark.parametrize("name", METHOD_NAMES)
def test_training_at_smoke_scale_lowers_the_loss(runs, name):
    records = MetricsLog(runs[name] / "metrics.jsonl").records()
    assert len(records) >= 3 and records[-1]["loss"] < records[0]["loss"]
    config = json.loads((runs[name] / RUN_FILE).read_text())
    assert config["train_scenes"] == 12


def test_training_is_deterministic_and_idempotent(runs, specs, smoke_dataset, tiny_backbone_spec, tmp_path):
    from ocplace.methods.no_llm.model import load_model

    again = specs["no_llm"].train(
        TrainContext(smoke_dataset, tiny_backbone_spec, tmp_path / "again", RECIPES["no_llm"])
    )
    assert load_model(again).sha256 == load_model(runs["no_llm"]).sha256
    model_file = runs["no_llm"] / WEIGHTS_FILE
    before = model_file.stat().st_mtime_ns
    assert (
        specs["no_llm"].train(TrainContext(smoke_dataset, tiny_backbone_spec, runs["no_llm"], RECIPES["no_llm"]))
        == runs["no_llm"]
    )
    assert model_file.stat().st_mtime_ns == before


def test_from_scratch_tower_is_deterministic(runs, specs, smoke_dataset, tiny_backbone_spec, tmp_path):
    again = specs["no_pretrain"].train(
        TrainContext(smoke_dataset, tiny_backbone_spec, tmp_path / "again", RECIPES["no_pretrain"])
    )
    read = lambda run: (run / "backbone" / "fingerprint.txt").read_text()  # noqa: E731
    assert read(again) == read(runs["no_pretrain"])
    first, second = (load_file(str(run / WEIGHTS_FILE)) for run in (runs["no_pretrain"], again))
    assert first.keys() == second.keys() and all(np.array_equal(first[k], second[k]) for k in first)


def test_fraction_trains_on_a_nested_subset(specs, isolated_cache, smoke_dataset, tiny_backbone_spec, tmp_path):
    run = specs["no_llm"].train(
        TrainContext(smoke_dataset, tiny_backbone_spec, tmp_path / "half", RECIPES["no_llm"], fraction=0.5)
    )
    assert json.loads((run / RUN_FILE).read_text())["train_scenes"] == 6


# ----------------------------------------------------------------------------- the methods


@pytest.mark.parametrize("name", METHOD_NAMES)
def test_method_places_every_scene_on_the_table(methods, scenes, name):
    outputs = methods[name].run(scenes, jax.random.key(0))
    assert len(outputs) == len(scenes)
    low, high = np.asarray(DEFAULT_TABLE.bounds[0]), np.asarray(DEFAULT_TABLE.bounds[1])
    placed = [o for o in outputs if o.failure is None]
    assert placed, [o.failure for o in outputs]
    for output, scene in zip(outputs, scenes):
        if output.failure is not None:
            assert output.mode is None
            continue
        assert output.samples.shape == (32, 2)
        assert np.all((output.mode >= low) & (output.mode <= high))
        assert np.all((output.samples >= low) & (output.samples <= high))
        assert output.grounded is not None
        assert all(0 <= t <= len(scene.boxes) for t in output.grounded)
        if name == "no_llm":
            assert output.parsed is None
            assert len(output.grounded) == (2 if scene.level == "2obj" else 1)
        else:
            assert len(output.parsed) == len(output.grounded)


@pytest.mark.parametrize("name", METHOD_NAMES)
def test_method_is_deterministic_for_a_key(methods, scenes, name):
    first, second = (methods[name].run(scenes, jax.random.key(7)) for _ in range(2))
    for a, b in zip(first, second):
        assert a.failure == b.failure and a.grounded == b.grounded and a.parsed == b.parsed
        if a.mode is not None:
            np.testing.assert_array_equal(a.mode, b.mode)
            np.testing.assert_array_equal(a.samples, b.samples)


@pytest.mark.parametrize("name", METHOD_NAMES)
def test_describe_is_json_with_weights_and_backbone(methods, name):
    described = json.loads(json.dumps(methods[name].describe()))
    assert len(described["backbone"]["fingerprint"]) == 64
    text = json.dumps(described)
    assert '"seed": 0' in text and "sha256" in text


def test_methods_are_registered():
    from ocplace.methods.registry import method_specs

    specs = method_specs()
    assert specs["no_llm"].label == "Ours w/o LLM" and specs["no_pretrain"].label == "Ours w/o CLIP pre-train"


def test_no_pretrain_is_ours_architecture_from_random_weights():
    import dataclasses

    from ocplace.methods.no_pretrain import recipe as no_pretrain_config
    from ocplace.models import offline_backbone as ob
    from ocplace.models import offline_config
    from ocplace.models.imagenet_weights import load_pretrained

    backbone = no_pretrain_config.default_config().backbone
    assert backbone.trunk_init == "random"
    assert dataclasses.replace(backbone, trunk_init="imagenet") == offline_config.default_config()
    smoke = no_pretrain_config.smoke_config().backbone
    params = ob.init_params(smoke, jax.random.key(0))
    imagenet = ob.flatten_params({"vision": load_pretrained(smoke.trunk)})
    random_trunk = ob.flatten_params({"vision": params["vision"]})
    assert random_trunk.keys() == imagenet.keys()
    assert not any(np.array_equal(random_trunk[k], imagenet[k]) for k in random_trunk if k.endswith("kernel"))


def test_calibration_keeps_a_random_trunk_alive(smoke_dataset):
    """A random EfficientNet with identity batch-norm statistics gives near-constant features;
    statistics measured on training images restore their spread across images."""
    from ocplace.methods.no_pretrain import model as no_pretrain
    from ocplace.methods.no_pretrain import recipe as no_pretrain_config
    from ocplace.methods.no_pretrain.train import no_pretrain_inputs
    from ocplace.models import efficientnet
    from ocplace.models import offline_backbone as ob
    from ocplace.models.backbone import PromptConfig

    model = no_pretrain_config.smoke_config()
    arrays = no_pretrain_inputs(smoke_dataset, "train", model.backbone, PromptConfig(), progress=False).arrays
    params = no_pretrain.init_params(model, jax.random.key(0))
    pixels = arrays["pixels"][arrays["visual_mask"].astype(bool)]

    def spread(backbone):
        features = np.asarray(efficientnet.features(backbone["vision"], pixels, model.backbone.trunk))
        return float(features.std(axis=0).mean())

    calibrated = no_pretrain.calibrate(model, params["backbone"], arrays)
    assert spread(params["backbone"]) < 1e-3 < 0.1 < spread(calibrated)
    assert (
        ob.flatten_params(calibrated["vision"]["params"]).keys()
        == ob.flatten_params(params["backbone"]["vision"]["params"]).keys()
    )
