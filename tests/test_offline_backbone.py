"""The offline backbone: captions, loss, pool, smoke pretraining, saving, loading, evaluation."""

from __future__ import annotations

import dataclasses
import functools
import json
import shutil

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ocplace import serial
from ocplace.errors import BackboneError, BackboneUnavailable, TrainingError
from ocplace.models import offline_backbone as ob
from ocplace.models import offline_config
from ocplace.models.backbone import Backbone, PromptConfig, load_backbone
from ocplace.models.offline_backbone import (
    FINGERPRINT_FILE,
    OfflineBackbone,
    compute_fingerprint,
    init_params,
    load_saved_backbone,
    minilm_digest,
)
from ocplace.models.offline_config import smoke_config as smoke_model
from ocplace.models.offline_recipes import (
    RECIPES,
    PretrainConfig,
    default_config,
    recipe_config,
    smoke_config,
    task_config,
)
from ocplace.paths import RUN_FILE, WEIGHTS_FILE
from ocplace.sim.library.types import CORPUS_SPLIT
from ocplace.train.pretrain.captions import ObjectDescription, build_caption_bank
from ocplace.train.pretrain.loss import contrastive_loss
from ocplace.train.pretrain.pool import training_pool


def _bowl(name, colour):
    return ObjectDescription(name, f"{colour} bowl", (f"{colour} ceramic bowl",), "bowl")


def _leaves_equal(a, b) -> bool:
    pairs = zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b), strict=True)
    return jax.tree_util.tree_structure(a) == jax.tree_util.tree_structure(b) and all(
        np.asarray(x).dtype == np.asarray(y).dtype and np.array_equal(x, y) for x, y in pairs
    )


# ----------------------------------------------------------------------------- captions and loss


def test_caption_bank_shares_category_captions_and_keeps_names_apart():
    prompt = PromptConfig()
    bank = build_caption_bank([_bowl("red_bowl", "red"), _bowl("white_bowl", "white")], prompt)
    index = {text: i for i, text in enumerate(bank.texts)}
    assert bank.class_names == ("red_bowl", "white_bowl", "table")
    assert bank.applies[index["a bowl"]].tolist() == [True, True, False]
    assert bank.applies[index[prompt.text_for("red bowl")]].tolist() == [True, False, False]
    assert bank.applies[index["something white"]].tolist() == [False, True, False]
    assert bank.applies[index[prompt.table_text]].tolist() == [False, False, True]
    for k, own in enumerate(bank.own):
        assert bank.applies[own, k].all()
    drawn = bank.sample(np.random.default_rng(0), np.array([0, 1, 2, 0]))
    assert bank.applies[drawn, [0, 1, 2, 0]].all()


def test_contrastive_loss_treats_repeated_objects_as_positives():
    # Images 0 and 1 show the same object and carry the same caption; image 2 another object.
    positives = jnp.array([[1, 1, 0], [1, 1, 0], [0, 0, 1]], bool)
    directions = jnp.eye(3)
    together = directions[jnp.array([0, 0, 1])]  # both views of the object embedded alike
    apart = directions[jnp.array([0, 2, 1])]  # the two views pushed apart
    label_aware = functools.partial(contrastive_loss, positives=positives, logit_scale=100.0)
    naive = functools.partial(contrastive_loss, positives=jnp.eye(3, dtype=bool), logit_scale=100.0)
    # The optimum of a soft-target cross-entropy is the targets' entropy: log 2 for each of the
    # duplicates in each direction, 0 for the single one.
    np.testing.assert_allclose(label_aware(together, together), 2 * np.log(2) / 3, rtol=1e-5)
    assert label_aware(apart, apart) > 10 * label_aware(together, together)
    # Plain diagonal targets would reward pulling the two views of one object apart.
    assert naive(apart, apart) < naive(together, together)
    assert label_aware(together, together[jnp.array([2, 2, 0])]) > 10 * label_aware(together, together)


def test_recipes_validate_and_hash_apart():
    from ocplace.cli.backbone import RECIPE_NAMES

    assert tuple(RECIPES) == RECIPE_NAMES
    keys = set()
    for name in RECIPES:
        config = recipe_config(name)
        config.validate()
        assert serial.from_json(PretrainConfig, serial.to_json(config)) == config
        keys.add(config.key())
    assert len(keys) == len(RECIPES)
    for field, value in (("pool", "library"), ("protocol", "lenient"), ("validation_share", 1.0)):
        bad = dataclasses.replace(
            default_config(), render=dataclasses.replace(default_config().render, **{field: value})
        )
        with pytest.raises(TrainingError, match=field):
            bad.validate()
    bad = dataclasses.replace(smoke_config(), optim=dataclasses.replace(smoke_config().optim, batch_size=1))
    with pytest.raises(TrainingError, match="batch_size"):
        bad.validate()


# ----------------------------------------------------------------------------- what may be rendered


def test_the_task_pool_holds_only_seen_objects_and_textures(library):
    config = task_config().render
    pool = training_pool(library, None, config)
    unseen_objects = set(library.names("unseen"))
    unseen_textures = {name for name, texture in library.textures.items() if texture.split == "unseen"}
    assert unseen_objects and unseen_textures
    assert set(pool.objects) == set(library.names("seen"))
    assert not set(pool.textures) & unseen_textures
    assert all(library.textures[name].split == "seen" for name in pool.textures)
    assert len(training_pool(library, None, dataclasses.replace(config, max_objects=4)).objects) == 4


def test_the_corpus_pool_holds_no_benchmark_object(library, corpus):
    pool = training_pool(library, corpus, default_config().render)
    assert len(pool.assets) >= 100
    assert not set(pool.objects) & set(library.objects)
    assert all(asset.split == CORPUS_SPLIT for asset in pool.assets)
    assert all(library.textures[name].split == "seen" for name in pool.textures)
    # A library object slipped into the corpus is refused, not rendered.
    intruder = library.get(library.names("seen")[0])
    leaky = dataclasses.replace(corpus, assets={**corpus.assets, intruder.name: intruder})
    with pytest.raises(TrainingError, match=intruder.name):
        training_pool(library, leaky, default_config().render)


# ----------------------------------------------------------------------------- smoke pretraining


@pytest.fixture(scope="module")
def smoke_run(tmp_path_factory, library):
    """One smoke pretraining run, recording every scene the arena builds."""
    from ocplace.sim.mujoco_backend import MujocoScenes
    from ocplace.train.pretrain.loop import pretrain

    built = []
    original = MujocoScenes.build

    def recording_build(self, spec, *args, **kwargs):
        built.append(spec)
        return original(self, spec, *args, **kwargs)

    out = tmp_path_factory.mktemp("offline") / "smoke"
    minilm_before = minilm_digest.__wrapped__(_minilm_dir())
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(MujocoScenes, "build", recording_build)
        result = pretrain(smoke_config(), library, out, progress=False, keep_run=True)
    return result, built, minilm_before


# Slow: the default suite's 15 min budget on 2 cores (docs/performance.md, session 12); the captions' sharing between
# seeds stays in it (test_pretrain_data.py)
@pytest.mark.slow
def test_a_backbone_seed_reads_the_renders_its_recipe_shares(smoke_run, library, corpus, tmp_path, monkeypatch):
    """`reproduce --backbone-seeds N`: every optimiser seed of a recipe trains on one set of renders, drawn once."""
    from ocplace.train.pretrain import loop, render

    config = smoke_config()
    pool = training_pool(library, corpus, config.render)
    repeat = dataclasses.replace(config, optim=dataclasses.replace(config.optim, seed=1))
    monkeypatch.setattr(loop, "output_dir", lambda recipe: tmp_path / "backbones" / f"offline-{recipe.key()}")
    shared = loop.shared_renders_dir(config, pool)
    assert shared == loop.shared_renders_dir(repeat, pool) and shared.parent == tmp_path / "backbones"
    other_images = dataclasses.replace(config, render=dataclasses.replace(config.render, seed=1))
    assert loop.shared_renders_dir(other_images, pool) != shared
    shutil.copytree(smoke_run[0].directory / "run" / "renders", shared / "renders")

    def rendering(*args, **kwargs):
        raise AssertionError("a seed of the recipe rendered its images again")

    monkeypatch.setattr(render, "render_chunks", rendering)
    result = loop.pretrain(repeat, library, tmp_path / "repeat", progress=False, stop_after=1, share_renders=True)
    assert np.isfinite(result.probe_loss_before) and not (tmp_path / "repeat" / "run" / "renders").exists()
    assert (shared / loop.CAPTIONS_FILE).is_file()  # its encoded captions, for the next seed


def _minilm_dir() -> str:
    from ocplace.models.minilm import minilm_path

    return minilm_path()


def test_smoke_pretraining_lowers_the_contrastive_loss(smoke_run):
    result = smoke_run[0]
    assert np.isfinite(result.probe_loss_before)
    assert result.probe_loss_after < result.probe_loss_before
    records = [json.loads(line) for line in (result.directory / "run" / "metrics.jsonl").read_text().splitlines()]
    assert records[-1]["step"] == smoke_config().optim.steps


def test_pretraining_renders_no_benchmark_object_or_unseen_texture(smoke_run, library, corpus):
    result, built, _ = smoke_run
    pool = training_pool(library, corpus, smoke_config().render)
    assert len(built) == smoke_config().render.scenes
    for spec in built:
        assert set(spec.objects) <= set(pool.objects)
        assert library.textures[spec.table_texture].split == "seen"
        assert not set(spec.objects) & set(library.objects)
    saved = json.loads((result.directory / "config.json").read_text())["pretraining"]["run"]
    assert saved["objects"] == list(pool.objects)


def test_saved_backbone_reloads_bit_identically(smoke_run):
    result = smoke_run[0]
    loaded = load_saved_backbone(result.directory)
    assert isinstance(loaded, Backbone)
    assert _leaves_equal(loaded.params, result.backbone.params)
    assert (
        loaded.fingerprint == result.backbone.fingerprint == (result.directory / FINGERPRINT_FILE).read_text().strip()
    )
    images = np.random.default_rng(0).integers(0, 256, size=(3, 57, 41, 3), dtype=np.uint8)
    texts = ["a photo of a red bowl.", "a photo of a table.", "ketchup"]
    assert np.array_equal(loaded.encode_images(images), result.backbone.encode_images(images))
    assert np.array_equal(loaded.encode_texts(texts), result.backbone.encode_texts(texts))
    features = loaded.encode_images(images)
    assert features.shape == (3, loaded.dim) and features.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(features, axis=1), 1.0, rtol=1e-5)
    assert load_backbone(f"offline:{result.directory}").fingerprint == loaded.fingerprint


def test_fingerprint_changes_with_the_weights(smoke_run):
    backbone = smoke_run[0].backbone
    digest = backbone.text_tower.digest
    params = jax.tree_util.tree_map(np.array, backbone.params)
    assert compute_fingerprint(backbone.config, params, digest) == backbone.fingerprint
    params["text_projection"][0, 0] = np.nextafter(params["text_projection"][0, 0], np.float32(np.inf))
    assert compute_fingerprint(backbone.config, params, digest) != backbone.fingerprint
    fresh = init_params(backbone.config, jax.random.key(0))
    assert compute_fingerprint(backbone.config, fresh, digest) != backbone.fingerprint


def test_corrupt_weights_are_refused(smoke_run, tmp_path):
    import shutil

    from safetensors.numpy import load_file, save_file

    copy = tmp_path / "copy"
    shutil.copytree(smoke_run[0].directory, copy, ignore=shutil.ignore_patterns("run"))
    weights = load_file(str(copy / WEIGHTS_FILE))
    weights["visual_projection"] = weights["visual_projection"] * 2
    save_file(weights, str(copy / WEIGHTS_FILE))
    with pytest.raises(BackboneError, match="fingerprint"):
        load_saved_backbone(copy)


def test_a_saved_backbone_is_loaded_once_per_process_until_its_fingerprint_changes(smoke_run, tmp_path):
    import shutil

    copy = tmp_path / "copy"
    shutil.copytree(smoke_run[0].directory, copy, ignore=shutil.ignore_patterns("run"))
    loaded = load_saved_backbone(copy)
    assert load_saved_backbone(copy) is loaded  # what a long-lived worker's next task gets
    (copy / FINGERPRINT_FILE).write_text("0" * 64 + "\n")  # another backbone saved there: read and verified again
    with pytest.raises(BackboneError, match="fingerprint"):
        load_saved_backbone(copy)


def test_text_tower_stays_frozen(smoke_run):
    from ocplace.models.minilm import load_minilm
    from ocplace.train.checkpoints import list_checkpoints

    result, _, minilm_before = smoke_run
    # The installed MiniLM files are unchanged, and are the ones the saved backbone names.
    assert minilm_digest.__wrapped__(_minilm_dir()) == minilm_before
    saved = json.loads((result.directory / "config.json").read_text())
    assert saved["text_tower"]["sha256"] == minilm_before
    # The backbone's sentence embeddings are exactly a freshly loaded MiniLM's.
    texts = ["a photo of a white bowl.", "the table"]
    assert np.array_equal(result.backbone.sentence_embeddings(texts), load_minilm(_minilm_dir())(texts))
    # Nothing of the text tower is trained: the trained state holds only the towers' own parameters.
    assert set(result.backbone.params) == {"vision", "visual_projection", "text_projection", "log_logit_scale"}
    from safetensors.numpy import load_file

    checkpoint = load_file(str(list_checkpoints(result.directory / "run")[-1]))
    trained = {key: value for key, value in checkpoint.items() if key.startswith("[0]")}
    config = result.backbone.config
    own, _ = ob.split_trainable(ob.trainable_mask(config, result.backbone.params), result.backbone.params)
    assert len(trained) == len(own) and sum(v.size for v in trained.values()) == sum(v.size for v in own.values())
    assert not [key for key in checkpoint if "word_embeddings" in key]


def test_pretraining_changes_only_the_trainable_part(smoke_run):
    """The ImageNet trunk's frozen blocks, its batch-norm statistics and its classifier are the
    packaged weights bit for bit after pretraining; every trainable leaf moved."""
    from ocplace.models.imagenet_weights import load_pretrained

    result = smoke_run[0]
    config, params = result.backbone.config, result.backbone.params
    assert config.trunk_init == "imagenet" and config.frozen_blocks > 0
    mask = ob.trainable_mask(config, params)
    imagenet = ob.flatten_params({"vision": load_pretrained(config.trunk)})
    trainable, frozen = ob.split_trainable(mask, params)
    frozen_trunk = {k: v for k, v in frozen.items() if k.startswith("vision/")}
    assert any("blocks_00" in k for k in frozen_trunk) and any("batch_stats" in k for k in frozen_trunk)
    assert all(np.array_equal(value, imagenet[key]) for key, value in frozen_trunk.items())
    tuned = {k: v for k, v in trainable.items() if k.startswith("vision/")}
    assert tuned and not any("classifier" in k for k in tuned)
    assert all(not np.array_equal(value, imagenet[key]) for key, value in tuned.items())


def test_pretraining_resumes_to_the_same_weights(smoke_run, library, tmp_path):
    import shutil

    from ocplace.train.pretrain.loop import pretrain

    full = smoke_run[0]
    out = tmp_path / "resumed"
    (out / "run").mkdir(parents=True)
    shutil.copytree(full.directory / "run" / "renders", out / "run" / "renders")
    shutil.copy(full.directory / "run" / RUN_FILE, out / "run" / RUN_FILE)
    partial = pretrain(smoke_config(), library, out, progress=False, stop_after=5)
    assert not (out / FINGERPRINT_FILE).exists()
    resumed = pretrain(smoke_config(), library, out, progress=False)
    assert _leaves_equal(resumed.backbone.params, full.backbone.params)
    assert resumed.backbone.fingerprint == full.backbone.fingerprint
    assert partial.backbone.fingerprint != full.backbone.fingerprint
    assert not (out / "run" / "renders").exists()


def test_a_run_directory_refuses_another_recipe(smoke_run, library):
    from ocplace.train.pretrain.loop import pretrain

    other = dataclasses.replace(smoke_config(), optim=dataclasses.replace(smoke_config().optim, seed=1))
    with pytest.raises(TrainingError, match="holds another run"):
        pretrain(other, library, smoke_run[0].directory, progress=False)


# ----------------------------------------------------------------------------- loading by spec


def test_offline_spec_without_a_built_backbone_says_how_to_build_it(tmp_path, monkeypatch):
    monkeypatch.setenv("OCPLACE_CACHE", str(tmp_path))
    with pytest.raises(BackboneUnavailable, match="ocplace backbone pretrain"):
        load_backbone("offline:default")
    with pytest.raises(BackboneUnavailable, match="neither a recipe"):
        load_backbone("offline:no_such_recipe")


def test_random_init_backbone_embeds_unit_rows():
    config = smoke_model()
    backbone = OfflineBackbone(config, init_params(config, jax.random.key(0)))
    images = np.zeros((2, 32, 32, 3), np.uint8)
    assert backbone.encode_images(images).shape == (2, config.embed_dim)
    assert backbone.encode_images(images[:0]).shape == (0, config.embed_dim)
    np.testing.assert_allclose(np.linalg.norm(backbone.encode_texts(["a bowl"]), axis=1), 1.0, rtol=1e-5)
    with pytest.raises(BackboneError, match="uint8"):
        backbone.encode_images(images.astype(np.float32))


# ----------------------------------------------------------------------------- evaluation


def test_zero_shot_evaluation_on_generated_scenes(smoke_run, library, tmp_path):
    from ocplace.sim.dataset.config import make_config
    from ocplace.sim.dataset.job import generate_dataset
    from ocplace.train.pretrain.evaluate import evaluate_split

    generate_dataset(tmp_path / "data", make_config(train=1, test=2), ["seen"], progress=False)
    result = evaluate_split(smoke_run[0].backbone, tmp_path / "data", "seen", library)
    grounding, retrieval = result["grounding"], result["retrieval"]
    assert grounding["scenes"] == 2 and grounding["tuples"] >= 2 and grounding["counts"]["all"] == grounding["tuples"]
    kinds = [grounding["counts"].get(kind, 0) for kind in ("object_tuples", "table_tuples")]
    assert sum(kinds) == grounding["tuples"]
    assert 0.0 <= grounding["all"] <= 1.0 and 0.0 < grounding["chance"] < 1.0
    assert retrieval["library"]["pool_size"] == len(library.names())
    assert retrieval["library"]["top1"] <= retrieval["library"]["top5"]


def test_backbone_path_command_prints_the_recipe_directory(tmp_path, monkeypatch, capsys):
    import argparse

    from ocplace.cli import backbone
    from ocplace.models.offline_recipes import recipe_dir

    monkeypatch.setenv("OCPLACE_CACHE", str(tmp_path))
    parser = argparse.ArgumentParser()
    backbone.register(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["backbone", "path", "--recipe", "demo"])
    assert args.func(args) == 0
    printed = capsys.readouterr().out.strip()
    assert printed == str(recipe_dir("demo")) and printed.startswith(str(tmp_path / "backbones" / "offline-"))


def test_a_vit_trunk_still_builds_encodes_and_round_trips(tmp_path):
    """The first offline backbone's ViT trunk (`vit_config`) still builds, encodes, saves and loads."""
    vit = dataclasses.replace(
        offline_config.vit_config(), image_size=32, patch_size=8, width=32, layers=1, heads=2, mlp_dim=64, embed_dim=16
    )
    params = init_params(vit, jax.random.key(0))
    assert params["visual_projection"].shape == (32, 16)
    assert all(jax.tree_util.tree_leaves(ob.trainable_mask(vit, params)))
    backbone = OfflineBackbone(vit, params)
    features = backbone.encode_images(np.random.default_rng(0).integers(0, 256, (3, 40, 50, 3), dtype=np.uint8))
    assert features.shape == (3, 16) and np.allclose(np.linalg.norm(features, axis=1), 1.0, atol=1e-5)
    loaded = load_saved_backbone(backbone.save(tmp_path / "vit"))
    assert loaded.config == vit and np.array_equal(
        loaded.encode_images(np.zeros((1, 32, 32, 3), np.uint8)),
        backbone.encode_images(np.zeros((1, 32, 32, 3), np.uint8)),
    )


def test_the_vit_depth_does_not_change_an_efficientnet_recipe_key():
    """Only what shapes the trunk keys a recipe: lite0's cached backbones survive ViT-only edits."""
    recipe = recipe_config("default")
    deeper = dataclasses.replace(recipe, model=dataclasses.replace(recipe.model, layers=12, heads=8))
    assert recipe.model.trunk == "lite0" and deeper.key() == recipe.key()
    assert serial.from_dict(PretrainConfig, serial.to_dict(deeper)) == recipe
    vit = dataclasses.replace(recipe, model=offline_config.vit_config())
    assert dataclasses.replace(vit, model=dataclasses.replace(vit.model, layers=12)).key() != vit.key()
