"""Pretraining data: recoloured objects, named primitives, their classes and captions, the unseen rule.

Renders are real MuJoCo scenes of the smoke recipe's pool, with primitives turned on.
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from ocplace.models.offline_recipes import default_config, smoke_config, task_config
from ocplace.sim.boxes import boxes_from_segmentation
from ocplace.sim.colour_terms import COLOUR_TERMS
from ocplace.sim.library.types import CORPUS_SPLIT
from ocplace.sim.primitives import PRIMITIVE_SPLIT, SHAPES, primitive_set, shape_mesh
from ocplace.train.pretrain.captions import (
    OBJECT,
    PRIMITIVE,
    RECOLOURED,
    TABLE,
    ObjectDescription,
    build_caption_bank,
    recoloured,
    with_colour,
)
from ocplace.train.pretrain.classes import caption_bank, leaks, mentions, pretraining_classes, unseen_names
from ocplace.train.pretrain.colours import recolour_objects
from ocplace.train.pretrain.pool import training_pool
from ocplace.train.pretrain.render import (
    paint,
    render_scene,
    scene_primitives,
    training_arena,
    with_primitives,
)

# The smoke recipe with primitives on and every object recoloured, so each scene shows both.
RENDER = dataclasses.replace(smoke_config().render, primitives_per_scene=2, recolour_share=1.0)
MODEL = smoke_config().model


@pytest.fixture(scope="module")
def setup(library, corpus):
    """`(pool, classes, arena)` of the smoke pool (four corpus models) with primitives."""
    pool = training_pool(library, corpus, RENDER)
    classes = pretraining_classes(library, pool.assets, RENDER)
    with training_arena(library, pool, scene_primitives(RENDER)) as arena:
        yield pool, classes, arena


@pytest.fixture(scope="module")
def scene(setup):
    """A settled smoke scene with its primitives painted: `(spec, painted, rgb, segmentation)`."""
    pool, classes, arena = setup
    from ocplace.sim.scene import sample_scene_spec

    rng = np.random.default_rng(3)
    spec = sample_scene_spec(rng, list(pool.objects), list(pool.textures), num_objects=RENDER.objects_per_scene)
    spec, painted = with_primitives(spec, classes, rng, RENDER)
    paint(arena.model, painted, rng)
    built = arena.build(spec)
    return built.spec, painted, built.rgb, built.segmentation


def _hsv(rgb: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV).astype(np.float64)


def _hue_distance(hue: np.ndarray, low: float, high: float) -> np.ndarray:
    """Distance (OpenCV hue units, on the 180 circle) of each hue from the range [low, high]."""
    centre, half = (low + high) / 2, (high - low) / 2
    offset = np.abs((hue - centre + 90) % 180 - 90)
    return np.maximum(offset - half, 0)


# ----------------------------------------------------------------------------- recolouring


@pytest.mark.parametrize("colour", ["blue", "red", "yellow", "white", "black", "grey"])
def test_recolouring_moves_the_object_to_its_colour_and_nothing_else(scene, colour):
    _, _, rgb, segmentation = scene
    target = int(np.bincount(segmentation[segmentation > 0]).argmax())  # the most visible object
    mask = segmentation == target
    out = recolour_objects(rgb, segmentation, {target: colour}, np.random.default_rng(0))
    assert out.dtype == np.uint8 and out.shape == rgb.shape
    assert np.array_equal(out[~mask], rgb[~mask])
    hsv, term = _hsv(out)[mask], COLOUR_TERMS[colour]
    if term.hue is not None:
        assert np.median(_hue_distance(hsv[:, 0], *term.hue)) <= 2
        assert np.median(hsv[:, 1]) >= term.saturation[0] - 5
    else:
        assert np.median(hsv[:, 1]) <= term.saturation[1] + 5
        low, high = term.value
        assert 0.45 * low - 5 <= np.median(hsv[:, 2]) <= high + 5


def test_recolouring_keeps_the_shading(scene):
    _, _, rgb, segmentation = scene
    target = int(np.bincount(segmentation[segmentation > 0]).argmax())
    mask = segmentation == target
    before = _hsv(rgb)[mask][:, 2]
    after = _hsv(recolour_objects(rgb, segmentation, {target: "green"}, np.random.default_rng(0)))[mask][:, 2]
    if before.std() > 3:  # a textured or shaded object: its value pattern survives
        assert np.corrcoef(before, after)[0, 1] > 0.8


def test_recoloured_crops_get_the_class_of_their_colour(setup):
    pool, classes, arena = setup
    images = render_scene(arena, pool, classes, 0, RENDER, MODEL)
    bank = caption_bank(classes)
    kinds = [bank.kinds[k] for k in images.labels]
    assert kinds.count(RECOLOURED) == kinds.count(OBJECT) > 0  # recolour_share 1: every crop twice
    assert kinds.count(TABLE) == RENDER.renders_per_scene
    for label in images.labels[np.array(kinds) == RECOLOURED]:
        body, colour = bank.class_names[label].split(":")
        assert body in pool.objects and colour in RENDER.colours
        assert f"something {colour}" in [bank.texts[i] for i in bank.own[label]]


# ----------------------------------------------------------------------------- primitives


@pytest.mark.parametrize("shape", SHAPES)
def test_primitive_meshes_rest_on_the_table_frame(shape):
    mesh = shape_mesh(shape, 0.08)
    low, high = mesh.bounds
    assert abs(low[2]) < 1e-9 and np.allclose((low[:2] + high[:2]) / 2, 0, atol=1e-9)
    assert max(mesh.extents[:2]) == pytest.approx(0.08, rel=0.25) and mesh.is_watertight


def test_primitives_settle_on_the_table_with_boxes_in_their_colour(setup, scene):
    spec, painted, _, segmentation = scene
    assert len(painted) == RENDER.primitives_per_scene and spec.objects[-len(painted) :] == tuple(painted)
    boxes = boxes_from_segmentation(segmentation)
    hsv = _hsv(scene[2])
    for body, colour in painted.items():
        object_id = spec.objects.index(body) + 1
        assert object_id in boxes.object_ids, f"{body} has no box"
        pixels, term = hsv[segmentation == object_id], COLOUR_TERMS[colour]
        if term.hue is not None:  # lit material colour: hue kept, shading varies
            assert np.median(_hue_distance(pixels[:, 0], *term.hue)) <= 6, (body, colour)
        else:
            assert np.median(pixels[:, 1]) <= 40, (body, colour)


def test_scenes_hold_primitives_with_their_classes(setup):
    pool, classes, arena = setup
    images = render_scene(arena, pool, classes, 1, RENDER, MODEL)
    bank = caption_bank(classes)
    primitive_labels = [k for k in images.labels if bank.kinds[k] == PRIMITIVE]
    assert primitive_labels
    for label in primitive_labels:
        body, colour = bank.class_names[label].split(":")
        assert body in {p.name for p in scene_primitives(RENDER)} and colour in RENDER.colours


# ----------------------------------------------------------------------------- captions


def test_every_class_has_captions_that_describe_it(library):
    config = task_config().render  # the training objects: names, synonyms and colours to check
    classes = pretraining_classes(library, training_pool(library, None, config).assets, config)
    bank = caption_bank(classes)
    assert bank.kinds.count(OBJECT) == len(classes.objects) and bank.table_class == len(classes.objects)
    assert len(bank.class_names) == len(classes.objects) + 1 + len(classes.extras)
    for k, own in enumerate(bank.own):
        assert len(own) >= 4 and bank.applies[own, k].all()
    index = {name: k for k, name in enumerate(bank.class_names)}
    text = {caption: i for i, caption in enumerate(bank.texts)}

    def described_by(caption):
        return {bank.class_names[k] for k in np.flatnonzero(bank.applies[text[caption]])}

    assert {"white_bowl", "white_bowl:blue", "red_bowl", "red_bowl:blue"} <= described_by("a bowl")
    assert {"white_bowl:blue", "red_bowl:blue"} <= described_by("a blue bowl")
    assert not described_by("a blue bowl") & {"white_bowl", "red_bowl"}
    assert "red_bowl:blue" not in described_by("a red bowl") and "white_bowl:red" in described_by("a red bowl")
    blue = described_by("something blue")
    assert {"blue_ketchup", "ketchup:blue", "primitive_cylinder_small:blue", "primitive_ring_large:blue"} <= blue
    assert not any(name.endswith(":red") for name in blue)
    assert described_by("a small blue cylinder") == {"primitive_cylinder_small:blue"}
    assert described_by("a blue cylinder") == {f"primitive_cylinder_{s}:blue" for s in ("small", "medium", "large")}
    assert len(described_by("a cylinder")) == 3 * len(config.colours)
    large_red_ring = [bank.texts[i] for i in bank.own[index["primitive_ring_large:red"]]]
    assert {"a large red ring", "a red ring", "a ring", "something red"} <= set(large_red_ring)
    # An object without a colour word gets one; names without a colour word still apply.
    basket = [bank.texts[i] for i in bank.own[index["basket:green"]]]
    assert {"a green wicker basket", "a green basket", "a wicker basket", "something green"} <= set(basket)


def test_colour_words_are_rewritten_not_stacked():
    assert with_colour("black and white bowl", "blue") == "blue bowl"
    assert with_colour("red ketchup bottle", "green") == "green ketchup bottle"
    assert with_colour("orange juice carton", "blue") == "blue orange juice carton"  # juice, not a colour
    bowl = recoloured(
        ObjectDescription("akita_black_bowl", "black patterned bowl", ("black and white bowl",), "bowl"), "pink"
    )
    assert bowl.colours == ("pink",) and bowl.kind == RECOLOURED and bowl.name == "akita_black_bowl:pink"


def test_a_bank_without_extras_keeps_the_old_layout():
    bowl = ObjectDescription("white_bowl", "white bowl", (), "bowl")
    bank = build_caption_bank([bowl])
    assert bank.class_names == ("white_bowl", "table") and bank.kinds == (OBJECT, TABLE) and bank.table_class == 1
    extra = build_caption_bank([bowl], extras=[recoloured(bowl, "blue")])
    assert extra.class_names == ("white_bowl", "table", "white_bowl:blue") and extra.table_class == 1


# ----------------------------------------------------------------------------- determinism


def test_a_scene_is_a_function_of_the_seed_and_its_index(setup):
    pool, classes, arena = setup
    first = render_scene(arena, pool, classes, 2, RENDER, MODEL)
    render_scene(arena, pool, classes, 3, RENDER, MODEL)  # other scenes in between change nothing
    again = render_scene(arena, pool, classes, 2, RENDER, MODEL)
    assert all(np.array_equal(getattr(first, f), getattr(again, f)) for f in ("images", "labels", "scenes"))
    other = render_scene(arena, pool, classes, 2, dataclasses.replace(RENDER, seed=1), MODEL)
    assert not (len(other.labels) == len(first.labels) and np.array_equal(other.images, first.images))


# ----------------------------------------------------------------------------- the unseen rule


def _phrases_of_unseen_textures(library):
    return [name.replace("_", " ") for name, texture in library.textures.items() if texture.split != "seen"]


def test_no_class_or_caption_names_an_unseen_object_or_texture(library):
    config = task_config().render
    pool = training_pool(library, None, config)
    classes = pretraining_classes(library, pool.assets, config)
    bank = caption_bank(classes)
    forbidden = unseen_names(library) + tuple(_phrases_of_unseen_textures(library))
    assert "yellow bowl" in forbidden and "red basket" in forbidden
    assert not [(c, n) for c in bank.texts for n in forbidden if mentions(c, n)]
    seen, primitives = set(library.names("seen")), {p.name for p in scene_primitives(config)}
    assert {extra.body for extra in classes.extras} <= seen | primitives
    assert not {name.split(":")[0] for name in bank.class_names} - seen - primitives - {"table"}
    # Recolourings that would be unseen objects are left out, not just renamed.
    assert "white_bowl:yellow" not in bank.class_names and "basket:red" not in bank.class_names
    assert "white_bowl:blue" in bank.class_names


def test_any_non_seen_split_blocks_its_names(library):
    """An object of another split (unseen_cat, ...) called "blue cylinder" removes the blue cylinders."""
    asset = library.get(library.names("seen")[0])
    intruder = dataclasses.replace(asset, name="intruder", human_name="blue cylinder", synonyms=(), split="unseen_cat")
    patched = dataclasses.replace(library, objects={**library.objects, "intruder": intruder})
    two = dataclasses.replace(task_config().render, max_objects=2, primitives_per_scene=2)
    classes = pretraining_classes(patched, training_pool(library, None, two).assets, two)
    names = {extra.description.name for extra in classes.extras}
    assert "primitive_cylinder_small:red" in names
    assert not [name for name in names if name.startswith("primitive_cylinder") and name.endswith(":blue")]


def test_the_pretraining_arena_holds_corpus_models_and_primitives_only(library, setup):
    pool, _, arena = setup
    seen_textures = {name for name, texture in library.textures.items() if texture.split == "seen"}
    primitives = {p.name for p in primitive_set(RENDER.primitive_shapes, RENDER.primitive_widths)}
    library_sources = {asset.source for asset in library.objects.values()}
    for name, asset in arena.objects.items():
        if asset.split == PRIMITIVE_SPLIT:
            assert name in primitives
        else:
            assert name in pool.objects and asset.split == CORPUS_SPLIT
            assert name not in library.objects and asset.source not in library_sources
    assert primitives <= set(arena.objects)
    materials = [arena.model.material(i).name for i in range(arena.model.nmat)]
    assert {m.removeprefix("table_") for m in materials if m.startswith("table_")} == set(pool.textures)
    assert set(pool.textures) <= seen_textures


def test_rendering_builds_only_pool_objects_and_primitives(library, corpus, tmp_path):
    from ocplace.sim.mujoco_backend import MujocoScenes
    from ocplace.train.pretrain.render import render_all

    built = []
    original = MujocoScenes.build

    def recording_build(self, spec, *args, **kwargs):
        built.append(spec)
        return original(self, spec, *args, **kwargs)

    pool = training_pool(library, corpus, RENDER)
    allowed = set(pool.objects) | {p.name for p in scene_primitives(RENDER)}
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(MujocoScenes, "build", recording_build)
        images = render_all(library, pool, tmp_path, RENDER, MODEL, progress=False)
    assert len(built) == RENDER.scenes and len(images.labels) == len(images.images)
    for spec in built:
        assert set(spec.objects) <= allowed and library.textures[spec.table_texture].split == "seen"
        assert len(set(spec.objects) - set(pool.objects)) == RENDER.primitives_per_scene


def test_chunks_rendered_in_two_processes_are_the_images_of_one(library, corpus, tmp_path, monkeypatch):
    """A scene is a function of its index, so the pretraining task renders its chunks in parallel processes."""
    from ocplace.train.pretrain import render
    from ocplace.train.pretrain.render import render_all

    pool = training_pool(library, corpus, RENDER)
    config = dataclasses.replace(RENDER, scenes=3, chunk_scenes=1)
    monkeypatch.setattr(render, "PARALLEL_MIN_SCENES", 3)  # the demo's 100 scenes in miniature
    one = render_all(library, pool, tmp_path / "one", config, MODEL, progress=False)
    two = render_all(library, pool, tmp_path / "two", config, MODEL, progress=False, workers=2)
    assert len(list((tmp_path / "two" / "renders").glob("chunk_*.npz"))) == 3
    for field in ("images", "labels", "scenes"):
        np.testing.assert_array_equal(getattr(one, field), getattr(two, field))


def test_a_pool_over_the_material_limit_renders_from_groups_that_each_fit(library, corpus, tmp_path):
    from ocplace.train.pretrain import render
    from ocplace.train.pretrain.render import arena_groups, render_all

    pool = training_pool(library, corpus, default_config().render)
    assert arena_groups(pool) == [pool]  # the tabletop corpus fits one arena: its renders are unchanged
    small = dataclasses.replace(pool, assets=pool.assets[:6])
    parts = sum(len(asset.visual_parts) for asset in small.assets)
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(render, "MAX_ARENA_PARTS", max(len(a.visual_parts) for a in small.assets) + 1)
        groups = arena_groups(small)
        assert len(groups) > 1 and len(groups) >= -(-parts // render.MAX_ARENA_PARTS)
        assert all(sum(len(a.visual_parts) for a in group.assets) <= render.MAX_ARENA_PARTS for group in groups)
        assert [a for group in groups for a in group.assets] == list(small.assets)
        config = dataclasses.replace(RENDER, scenes=len(groups), objects_per_scene=1, primitives_per_scene=0)
        images = render_all(library, small, tmp_path, config, MODEL, progress=False)
    names = [asset.name for asset in small.assets]
    for scene, group in enumerate(groups):  # scene i shows an object of group i (classes 0..N-1: as rendered)
        labels = images.labels[(images.scenes == scene) & (images.labels < len(names))]
        assert len(labels) and {names[label] for label in labels} <= set(group.objects)


def test_render_knobs_are_validated():
    assert not RENDER.problems() and not default_config().render.problems()
    for bad in (
        {"colours": ("teal",)},
        {"primitives_per_scene": 10},
        {"recolour_share": 1.5},
        {"primitive_widths": (0.1, 0.05, 0.2)},
        {"primitive_shapes": ("star",)},
    ):
        assert dataclasses.replace(RENDER, **bad).problems(), bad


# ----------------------------------------------------------------------------- captions a run reads


def test_a_run_encodes_only_the_captions_it_draws_with_the_bits_of_the_whole_bank(setup):
    from ocplace.models.offline_backbone import FrozenTextTower
    from ocplace.train.pretrain.loop import (
        caption_sentences,
        draw_batch,
        probe_rng,
        run_draws,
        step_rng,
        used_captions,
    )
    from ocplace.train.pretrain.render import RenderedImages

    _, classes, _ = setup
    bank = caption_bank(classes)
    labels = np.repeat(np.arange(len(bank.class_names), dtype=np.int32), 2)  # two images of every class
    images = RenderedImages(np.zeros((len(labels), 4, 4, 3), np.uint8), labels, np.zeros_like(labels))
    by_class = [np.flatnonzero(labels == k) for k in range(len(bank.class_names))]
    optim = dataclasses.replace(smoke_config().optim, steps=3, batch_size=16)
    draws, probe_draw = run_draws(images, by_class, bank, optim)
    used = used_captions([*draws, probe_draw])
    steps = [draw_batch(images, by_class, bank, optim, step_rng(optim.seed, step)).captions for step in range(3)]
    probe = draw_batch(images, by_class, bank, optim, probe_rng(optim.seed), augment=False).captions
    assert set(used) == set(np.concatenate([*steps, probe])) and 0 < len(used) < len(bank.texts)

    tower = FrozenTextTower.load(MODEL.text_max_length)
    sentences = caption_sentences(tower, bank.texts, used)
    whole = np.concatenate([tower.encode(list(bank.texts[i : i + 64])) for i in range(0, len(bank.texts), 64)])
    assert np.array_equal(sentences[used], whole[used])  # other neighbours in the batch, the same bits
    assert not sentences[np.setdiff1d(np.arange(len(bank.texts)), used)].any()
    # A last batch of 5 (which the tower alone would pad to 8 rows, not 64) gives the same bits too.
    odd = np.random.default_rng(0).choice(len(bank.texts), size=69, replace=False)
    assert np.array_equal(caption_sentences(tower, bank.texts, np.sort(odd))[odd], whole[odd])


def test_backbone_seeds_encode_each_caption_once_with_the_bits_of_their_own_encoding(setup, tmp_path):
    from ocplace.models.offline_backbone import FrozenTextTower
    from ocplace.train.pretrain.loop import caption_sentences, shared_caption_sentences

    texts = caption_bank(setup[1]).texts[:200]
    tower = FrozenTextTower.load(MODEL.text_max_length)
    encoded = []
    counting = dataclasses.replace(tower, encode=lambda batch: encoded.append(len(set(batch))) or tower.encode(batch))
    first, second = np.arange(0, 120), np.arange(60, 200)
    assert np.array_equal(
        shared_caption_sentences(counting, texts, first, tmp_path), caption_sentences(tower, texts, first)
    )
    assert sum(encoded) == 120
    mine = shared_caption_sentences(counting, texts, second, tmp_path)
    assert sum(encoded) == 120 + 80  # the 60 the first seed encoded are read, not encoded again
    assert np.array_equal(mine, caption_sentences(tower, texts, second))  # zeros outside its own, the same bits
    assert np.array_equal(
        shared_caption_sentences(counting, texts, first, tmp_path), caption_sentences(tower, texts, first)
    )
    assert sum(encoded) == 200
    other_bank = (*texts[:-1], "a photo of something else.")
    shared_caption_sentences(counting, other_bank, first, tmp_path)
    assert sum(encoded) == 320  # another bank's captions are not this one's


def test_group_balance_weighs_a_category_of_many_models_as_one():
    from ocplace.train.pretrain.captions import OBJECT, TABLE, CaptionBank
    from ocplace.train.pretrain.loop import sample_classes

    groups = ("plug",) * 10 + ("teapot", "lamp", TABLE)
    kinds = (OBJECT,) * 12 + (TABLE,)
    bank = CaptionBank(
        tuple(map(str, range(13))), ("a",), np.ones((1, 13), bool), (np.zeros(1, np.int32),) * 13, kinds, groups
    )
    by_class = [np.array([k]) for k in range(13)]
    optim = dataclasses.replace(smoke_config().optim, kind_shares=(("object", 1.0),))
    teapot_share = {}
    for balance in ("class", "group"):
        drawn = sample_classes(
            by_class, bank, dataclasses.replace(optim, balance=balance), np.random.default_rng(0), 6000
        )
        assert set(drawn.tolist()) == set(range(12))  # every object class, never the table
        teapot_share[balance] = float(np.mean(drawn == 10))
    assert teapot_share["class"] == pytest.approx(1 / 12, abs=0.015)
    assert teapot_share["group"] == pytest.approx(1 / 3, abs=0.03)
    assert dataclasses.replace(optim, balance="category").problems()


def test_open_colour_captions_keep_corpus_recolourings_that_name_a_test_object(library, corpus):
    from ocplace.train.pretrain.pool import training_pool

    open_rule = default_config().render  # rule C kept the open captions (docs/settings.md)
    seen_rule = dataclasses.replace(open_rule, colour_captions="seen")
    assert open_rule.colour_captions == "open"
    assets = training_pool(library, corpus, seen_rule).assets
    kept = {extra.description.name for extra in pretraining_classes(library, assets, seen_rule).extras}
    widened = {extra.description.name for extra in pretraining_classes(library, assets, open_rule).extras}
    forbidden = unseen_names(library)
    added = [
        extra for extra in pretraining_classes(library, assets, open_rule).extras if extra.description.name not in kept
    ]
    assert kept < widened and added
    assert all(leaks(extra.description, forbidden) for extra in added)  # exactly the ones the rule dropped
    for bad in ({"protocol": "strict"}, {"pool": "task"}):
        assert dataclasses.replace(open_rule, **bad).problems()
    assert not open_rule.problems()


@pytest.mark.parametrize("damage", ["an edited image", "a truncated file", "an older chunk without a checksum"])
def test_a_damaged_rendered_chunk_is_rendered_again_never_used(library, corpus, tmp_path, damage, caplog):
    """Issue 60, item 7: the shared renders are reused by every backbone seed of a recipe, so each chunk carries the
    sha256 of its arrays; a chunk that no longer matches is rendered again (said in one line), giving the same
    images as before."""
    import dataclasses

    from ocplace.train.pretrain import render
    from ocplace.train.pretrain.render import chunk_path, render_all

    config = dataclasses.replace(RENDER, chunk_scenes=1)
    pool = training_pool(library, corpus, config)
    first = render_all(library, pool, tmp_path, config, MODEL, progress=False)
    path = chunk_path(tmp_path, 0)
    with np.load(path) as stored:
        arrays = dict(stored)
    if damage == "an edited image":
        arrays["images"] = arrays["images"].copy()
        arrays["images"][0, 0, 0] ^= 0xFF
        np.savez(path, **arrays)
    elif damage == "a truncated file":
        path.write_bytes(path.read_bytes()[:300])
    else:
        np.savez(path, **{k: v for k, v in arrays.items() if k != "sha256"})
    rendered = []
    original = render.render_chunks
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(render, "render_chunks", lambda *a, **k: (rendered.append(list(a[5])), original(*a, **k))[1])
        again = render_all(library, pool, tmp_path, config, MODEL, progress=False)
    assert rendered == [[0]] and "it is rendered again" in caplog.text
    assert all(np.array_equal(getattr(first, f), getattr(again, f)) for f in ("images", "labels", "scenes"))


def test_edited_caption_sentences_are_encoded_again(tmp_path, caplog):
    """The shared `captions.npz` carries its checksum too: edited sentences are never read as the tower's."""
    from ocplace.models.offline_backbone import FrozenTextTower
    from ocplace.train.pretrain.loop import CAPTIONS_FILE, shared_caption_sentences

    tower = FrozenTextTower.load(MODEL.text_max_length)
    texts, used = ("a photo of a red box.", "a photo of a blue ball."), np.arange(2)
    first = shared_caption_sentences(tower, texts, used, tmp_path)
    with np.load(tmp_path / CAPTIONS_FILE) as stored:
        arrays = dict(stored)
    arrays["sentences"] = arrays["sentences"] + 1.0
    np.savez(tmp_path / CAPTIONS_FILE, **arrays)
    again = shared_caption_sentences(tower, texts, used, tmp_path)
    assert np.array_equal(first, again) and "they are encoded again" in caplog.text
