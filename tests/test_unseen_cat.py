"""The unseen_cat test subset: objects of categories that no training object belongs to."""

import subprocess
import zipfile

import mujoco
import numpy as np
import pytest

from ocplace.errors import MissingAssetPackage, SceneError
from ocplace.eval import table
from ocplace.models.offline_recipes import default_config, strict_config, task_config
from ocplace.sim.dataset.config import smoke_config
from ocplace.sim.dataset.job import scene_dirs
from ocplace.sim.dataset.records import read_scene
from ocplace.sim.library import robosuite_assets
from ocplace.sim.library.metadata import packaged_objects
from ocplace.sim.library.types import CORPUS_SPLIT
from ocplace.sim.primitives import SHAPES
from ocplace.sim.scene import sample_scene_spec
from ocplace.train.pretrain.pool import training_pool
from ocplace.vocabulary import TEST_SUBSETS


def _specs(split):
    return [spec for spec in packaged_objects() if spec.split == split]


def _head_noun(text):
    return text.split()[-1]


def test_unseen_cat_categories_are_disjoint_from_seen_ones():
    seen = {spec.category for spec in _specs("seen")}
    unseen_cat = _specs("unseen_cat")
    categories = {spec.category for spec in unseen_cat}
    assert len(unseen_cat) >= 8 and len(categories) >= 6  # enough for varied 5-object scenes
    assert not categories & seen
    # Also by head noun ("wooden tray" is a tray): no unseen_cat name or category ends in a seen one.
    seen_nouns = {_head_noun(category) for category in seen}
    for spec in unseen_cat:
        assert _head_noun(spec.category) not in seen_nouns, spec.name
        assert _head_noun(spec.human_name) not in seen_nouns, spec.name
    # The unseen_obj subset keeps only categories that training has.
    assert {spec.category for spec in _specs("unseen")} <= seen
    # Pretraining also shows named primitive shapes: none is an unseen_cat category either.
    assert not {_head_noun(category) for category in categories} & set(SHAPES)


def test_library_holds_every_unseen_cat_object_as_a_loadable_model(library):
    wanted = {spec.name for spec in _specs("unseen_cat")}
    assert set(library.names("unseen_cat")) == wanted
    for name in wanted:
        asset = library.get(name)
        model = mujoco.MjModel.from_xml_path(str(asset.mjcf))
        assert model.ngeom >= len(asset.hulls), name
        assert 0.005 <= max(asset.extents) <= 0.35, (name, asset.extents)
    assert library.get("lemon").source.startswith("robosuite:") and library.get("lemon").texture is not None


def test_unseen_cat_scenes_hold_only_unseen_cat_objects(smoke_dataset, library):
    assert "unseen_cat" in TEST_SUBSETS
    dirs = scene_dirs(smoke_dataset, "unseen_cat")
    assert len(dirs) == smoke_config().split("unseen_cat").num_scenes == 8
    for directory in dirs:
        record = read_scene(directory)
        names = [obj.name for obj in record.objects] + [record.held_object.name]
        assert all(library.get(name).split == "unseen_cat" for name in names), names
        assert library.textures[record.table_texture].split == "unseen"
        assert record.instruction_style == "seen"


def test_a_small_pool_is_used_whole_and_a_too_small_one_refused():
    pool = [f"object_{k}" for k in range(6)]  # the least a scene and its held object need
    for seed in range(5):
        spec = sample_scene_spec(np.random.default_rng(seed), pool, ["table"])
        assert sorted((*spec.objects, spec.held_object)) == pool
    with pytest.raises(SceneError, match="need at least 6 objects"):
        sample_scene_spec(np.random.default_rng(0), pool[:5], ["table"])


def test_pretraining_pools_never_hold_unseen_cat_objects(library, corpus):
    assert library.names("unseen_cat")
    for config in (default_config().render, strict_config().render, task_config().render):
        pool = training_pool(library, corpus, config)
        assert not set(pool.objects) & set(library.names("unseen_cat"))
        assert all(asset.split in ("seen", CORPUS_SPLIT) for asset in pool.assets)


def test_table_one_keeps_the_papers_unseen_mean():
    def subset(success):
        return {"aggregate": {"overall": {"success": success}}}

    entry = {
        "subsets": {
            "seen": subset(0.9),
            "unseen_obj": subset(0.6),
            "unseen_inst": subset(0.8),
            "unseen_cat": subset(0.0),
        }
    }
    assert table.unseen_mean(entry) == pytest.approx(0.7)  # unseen_cat is reported, never averaged in


# ----------------------------------------------------------------------------- robosuite's files


def _fake_wheel(path):
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("robosuite/models/assets/objects/lemon.xml", '<texture file="../textures/lemon.png"/>')
        archive.writestr("robosuite/models/assets/objects/meshes/lemon.obj", "v 0 0 0\n")
        archive.writestr("robosuite/models/assets/textures/lemon.png", b"png")
        archive.writestr("robosuite/models/assets/textures/brick.png", b"unused")
        archive.writestr("robosuite/models/robots/arm.xml", "<robot/>")
        archive.writestr("robosuite-1.5.2.dist-info/licenses/LICENSE", "MIT License")


def test_robosuite_objects_come_from_a_wheel_in_the_sources_folder(tmp_path, monkeypatch):
    monkeypatch.setenv("OCPLACE_CACHE", str(tmp_path))
    (tmp_path / "sources").mkdir()
    _fake_wheel(tmp_path / "sources" / robosuite_assets.WHEEL_NAME)
    root = robosuite_assets.robosuite_root()
    kept = sorted(str(p.relative_to(root)) for p in root.rglob("*") if p.is_file())
    assert kept == ["LICENSE", "objects/lemon.xml", "objects/meshes/lemon.obj", "textures/lemon.png"]
    assert robosuite_assets.robosuite_root() == root  # second call: no extraction


def test_robosuite_download_failure_says_what_to_do(tmp_path, monkeypatch):
    monkeypatch.setenv("OCPLACE_CACHE", str(tmp_path))

    def offline(*args, **kwargs):
        raise subprocess.CalledProcessError(1, args[0], stderr="ERROR: No matching distribution found")

    monkeypatch.setattr(robosuite_assets.subprocess, "run", offline)
    with pytest.raises(MissingAssetPackage, match="pip download --no-deps robosuite==1.5.2"):
        robosuite_assets.robosuite_root()


def test_a_wheel_member_outside_its_folder_is_refused_and_nothing_escapes(tmp_path, monkeypatch):
    monkeypatch.setenv("OCPLACE_CACHE", str(tmp_path / "cache"))
    (tmp_path / "cache" / "sources").mkdir(parents=True)
    wheel = tmp_path / "cache" / "sources" / robosuite_assets.WHEEL_NAME
    _fake_wheel(wheel)
    with zipfile.ZipFile(wheel, "a") as archive:
        archive.writestr("robosuite/models/assets/objects/../../../../../../../escaped.txt", "x")
    with pytest.raises(MissingAssetPackage, match="outside its folder"):
        robosuite_assets.robosuite_root()
    assert not list(tmp_path.rglob("escaped.txt"))
