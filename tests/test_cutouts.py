"""Cut-outs: named 2-D images (Tux Paint's stamps, Fluent Emoji) as thin textured prisms of the pretraining
corpus: the mesh, reading each source, fetching the emoji, bad input, the sources a recipe asks for, and the
real stamps when they are installed."""

from __future__ import annotations

import dataclasses
import logging
import os
import shutil
import tarfile
import zipfile
from pathlib import Path

import mujoco
import numpy as np
import pytest
import trimesh
from PIL import Image

from ocplace import serial
from ocplace.errors import CorpusError, MissingAssetPackage, TrainingError
from ocplace.models.offline_recipes import default_config
from ocplace.sim.corpus import cutout
from ocplace.sim.corpus.build import ATTRIBUTION_FILE, build_corpus, load_corpus
from ocplace.sim.corpus.emoji import EMOJI_ENV, EMOJI_INSTALL_HINT, EMOJI_TARBALL, emoji_name, fetch_emoji
from ocplace.sim.corpus.selection import is_validation_group
from ocplace.sim.corpus.stamps import DEFAULT_STAMPS, STAMPS_ENV, STAMPS_INSTALL_HINT, stamp_name
from ocplace.train.pretrain.pool import strict_drops, training_pool, validation_groups

THICKNESS = 0.01


def _ring(size: int = 96) -> np.ndarray:
    """An RGBA ring (a hole in the middle), red on the left half and blue on the right, `(size, size, 4)`."""
    ys, xs = np.mgrid[:size, :size] - (size - 1) / 2
    radius = np.hypot(xs, ys)
    image = np.zeros((size, size, 4), np.uint8)
    image[..., 3] = np.where((radius < size * 0.45) & (radius > size * 0.2), 255, 0)
    image[..., 0] = np.where(xs < 0, 220, 20)
    image[..., 2] = np.where(xs < 0, 20, 220)
    return image


def _write_stamp(folder: Path, stem: str, image: np.ndarray | None, description: bytes | None = b"A ring.\n"):
    folder.mkdir(parents=True, exist_ok=True)
    if image is not None:
        Image.fromarray(image).save(folder / f"{stem}.png")
    if description is not None:
        (folder / f"{stem}.txt").write_bytes(description + b"fr.utf8=Un anneau.\n")


def test_a_ring_becomes_a_closed_flat_prism_with_its_hole_and_planar_uvs():
    image = Image.fromarray(_ring())
    rgb, mask = cutout.mask_of(image)
    mesh = cutout.cutout_mesh(mask, cutout.filled_texture(rgb, mask), 0.15, THICKNESS)
    solid = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
    assert solid.is_winding_consistent and solid.volume > 0
    assert np.ptp(mesh.vertices[:, :2], axis=0).max() == pytest.approx(0.15, rel=0.02)
    assert set(np.round(mesh.vertices[:, 2], 6)) == {0.0, THICKNESS}
    assert np.allclose(mesh.vertices[:, :2].min(axis=0), -mesh.vertices[:, :2].max(axis=0), atol=2e-3)
    top = solid.face_normals[:, 2] > 0.99
    pixel = 0.15 / mask.shape[1]
    assert solid.area_faces[top].sum() == pytest.approx(mask.sum() * pixel**2, rel=0.06)
    assert solid.volume == pytest.approx(solid.area_faces[top].sum() * THICKNESS, rel=1e-6)
    assert np.hypot(*solid.triangles_center[top][:, :2].T).min() > 0.025  # the hole (r = 0.033 m) stays a hole
    # Planar UVs: the top's left side samples the red half of the texture, its right side the blue half.
    texture = np.asarray(mesh.texture)
    for side, channel in ((-1, 0), (1, 2)):
        vertex = np.argmax(side * mesh.vertices[:, 0])
        u, v = mesh.uv[vertex]
        x, y = min(int(u * texture.shape[1]), texture.shape[1] - 1), min(int((1 - v) * texture.shape[0]), 95)
        assert np.argmax(texture[y, x]) == channel


@pytest.mark.parametrize(
    "pixels, why",
    [
        (np.zeros((64, 64, 3), np.uint8), "no alpha"),
        (np.zeros((64, 64, 4), np.uint8), "empty"),
        (np.pad(np.full((20, 30, 4), 255, np.uint8), ((10, 10), (10, 10), (0, 0))), "under 32 px"),
    ],
)
def test_unusable_images_are_typed_errors(pixels, why):
    with pytest.raises(CorpusError, match=why):
        cutout.mask_of(Image.fromarray(pixels))


def test_a_stamp_is_named_by_its_description_or_its_file():
    assert stamp_name("A green apple.", "apple_green") == "green apple"
    assert stamp_name("An adjustable wrench.", "wrench_adjustable") == "adjustable wrench"
    assert stamp_name("Seville orange, also called a bitter orange.", "orange_seville") == "seville orange"
    assert stamp_name("Remember to flush the toilet and wash your hands.", "toilet") == "toilet"
    assert stamp_name("", "025quarter") == "quarter"


def test_an_emoji_is_named_by_unicode_and_kept_only_when_it_is_a_thing():
    assert emoji_name("1f34e") == "red apple" and emoji_name("1f4a1") == "electric light bulb"
    assert emoji_name("1F9F8") == "teddy bear" and emoji_name("2615") == ""  # hot beverage: outside the blocks
    for stem in ("1f600", "1f44d", "1f1fa-1f1f8", "1f468-200d-1f373", "2764-fe0f", "1f7e5", "zz", ""):
        assert emoji_name(stem) == "", stem  # a face, a hand, a flag, a sequence, a heart, a square, no number


@pytest.fixture
def own_cache(tmp_path, monkeypatch):
    cache = tmp_path / "cache"
    monkeypatch.setenv("OCPLACE_CACHE", str(cache))
    monkeypatch.setenv(STAMPS_ENV, str(tmp_path / "no-stamps"))
    monkeypatch.setenv(EMOJI_ENV, str(tmp_path / "no-emoji"))
    return cache


def _catalogue(source: Path, names: list[str]) -> None:
    """A `.sh3f` of untextured 10 x 8 x 6 cm boxes named `names` (the tabletop corpus of these tests)."""
    obj = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\n" + "".join(
        f"f {a} {b} {c}\n"
        for a, b, c in [(1, 3, 2), (1, 4, 3), (5, 6, 7), (5, 7, 8), (1, 2, 6), (1, 6, 5)]
        + [(2, 3, 7), (2, 7, 6), (3, 4, 8), (3, 8, 7), (4, 1, 5), (4, 5, 8)]
    )
    lines = ["id=test"]
    source.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(source / "Boxes.sh3f", "w") as archive:
        for index, name in enumerate(names, start=1):
            lines += [f"name#{index}={name}", f"model#{index}=/b{index}/box.obj"]
            lines += [f"width#{index}=10", f"depth#{index}=8", f"height#{index}=6", f"category#{index}=Misc"]
            archive.writestr(f"b{index}/box.obj", obj)
        archive.writestr("PluginFurnitureCatalog.properties", "\n".join(lines) + "\n")


def _listing(directory: Path) -> dict[str, int]:
    return {str(p.relative_to(directory)): p.stat().st_mtime_ns for p in directory.rglob("*")}


def test_stamps_convert_only_when_asked_and_bad_ones_are_skipped_with_one_warning(tmp_path, own_cache, caplog):
    source, stamps = tmp_path / "catalogues", tmp_path / "stamps"
    _catalogue(source, ["Blue box"])
    _write_stamp(stamps / "household", "ring", _ring())
    _write_stamp(stamps / "household", "ring_mirror", _ring())  # a mirrored copy: left out
    _write_stamp(stamps / "symbols", "sign", _ring())  # not a folder of things: left out
    _write_stamp(stamps / "food", "opaque", _ring()[..., :3])  # no alpha
    _write_stamp(stamps / "food", "clear", np.zeros((64, 64, 4), np.uint8))  # an empty mask
    _write_stamp(stamps / "food", "tiny", _ring(24))  # under 32 px
    _write_stamp(stamps / "food", "latin", _ring(), b"Un anneau \xe9tranger.\n")  # not UTF-8
    _write_stamp(stamps / "food", "silent", _ring(), None)  # no description
    (tmp_path / "secret.png").write_bytes((stamps / "household" / "ring.png").read_bytes())
    (stamps / "food" / "escape.png").symlink_to(tmp_path / "secret.png")  # leads outside the package
    shutil.copy(stamps / "household" / "ring.txt", stamps / "food" / "escape.txt")
    before = _listing(tmp_path)

    folders = {"stamps": stamps}
    plain = build_corpus(source, progress=False, cutout_folders=folders)
    assert not plain.cutouts and list(plain.assets) == ["boxes-001"]
    assert "cut-out source stamps was not asked for" in {m.entry.name: m.reason for m in plain.models}["ring"]
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        corpus = build_corpus(source, progress=False, cutouts=("stamps",), cutout_folders=folders)
    assert len(corpus.cutouts) == 1
    (name,) = corpus.cutouts
    assert (
        corpus.cutouts[name] == "stamps"
        and corpus.assets[name].human_name == "ring"
        and corpus.assets[name].source.endswith("household/ring.png")
    )
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1 and "6 models skipped" in warnings[0]
    for problem in ("no alpha", "alpha mask is empty", "under 32 px", "not UTF-8", "no description", "outside"):
        assert problem in warnings[0], problem
    assert "tuxpaint" in (own_cache / "corpus" / ATTRIBUTION_FILE).read_text()
    ring = corpus.assets[name]
    model = mujoco.MjModel.from_xml_path(str(ring.mjcf))
    assert model.ntex == 1 and ring.extents[2] == pytest.approx(THICKNESS, abs=1e-6)
    assert {k: v for k, v in _listing(tmp_path).items() if not k.startswith("cache")} == before
    assert load_corpus().cutouts == {name: "stamps"}
    assert build_corpus(source, progress=False, cutout_folders=folders).cutouts == {name: "stamps"}  # kept after


def test_missing_sources_are_a_warning_and_a_source_with_nothing_usable_a_typed_error(
    tmp_path, own_cache, caplog, monkeypatch
):
    source, stamps = tmp_path / "catalogues", tmp_path / "stamps"
    _catalogue(source, ["Blue box"])
    monkeypatch.delenv(EMOJI_ENV)
    monkeypatch.setenv("PATH", str(tmp_path / "no-programs"))  # no npm to fetch the emoji with
    with caplog.at_level(logging.WARNING):
        corpus = build_corpus(source, progress=False, cutouts=("stamps", "emoji"))
    assert list(corpus.assets) == ["boxes-001"]
    warnings = " ".join(r.getMessage() for r in caplog.records if r.levelno == logging.WARNING)
    assert STAMPS_INSTALL_HINT in warnings and EMOJI_INSTALL_HINT in warnings
    _write_stamp(stamps / "food", "clear", np.zeros((64, 64, 4), np.uint8))
    with pytest.raises(CorpusError, match="no usable image"):
        build_corpus(source, progress=False, cutouts=("stamps",), cutout_folders={"stamps": stamps})
    with pytest.raises(CorpusError, match="unknown cut-out sources"):
        build_corpus(source, progress=False, cutouts=("photos",))


def _webp(path: Path, image: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(image).save(path, format="WEBP", lossless=True)


def test_emoji_are_fetched_from_their_tarball_and_become_cut_outs(tmp_path, own_cache, monkeypatch):
    package = tmp_path / "package-src"
    for stem in ("1f34e", "1f4a1", "1f600", "1f1fa-1f1f8"):  # red apple, light bulb; a face and a flag left out
        _webp(package / "package" / "assets" / f"{stem}.webp", _ring())
    sources = own_cache / "sources"
    sources.mkdir(parents=True)
    with tarfile.open(sources / EMOJI_TARBALL, "w:gz") as archive:
        archive.add(package / "package", arcname="package")
    _catalogue(tmp_path / "catalogues", ["Blue box"])
    assert fetch_emoji() == tmp_path / "no-emoji" and not (tmp_path / "no-emoji").exists()  # a named folder: as is
    monkeypatch.delenv(EMOJI_ENV)
    corpus = build_corpus(tmp_path / "catalogues", progress=False, cutouts=("emoji",))
    assert sorted(corpus.assets[n].human_name for n in corpus.cutouts) == ["electric light bulb", "red apple"]
    assert set(corpus.cutouts.values()) == {"emoji"}
    assert fetch_emoji().is_dir() and not [p for p in sources.iterdir() if p.name.startswith(".unpack")]


def test_an_emoji_tarball_that_leads_outside_is_refused(tmp_path, own_cache, monkeypatch):
    monkeypatch.delenv(EMOJI_ENV)
    (tmp_path / "evil.webp").write_bytes(b"x")
    sources = own_cache / "sources"
    sources.mkdir(parents=True)
    with tarfile.open(sources / EMOJI_TARBALL, "w:gz") as archive:
        archive.add(tmp_path / "evil.webp", arcname="../../evil.webp")
    with pytest.raises(MissingAssetPackage, match="cannot be unpacked"):
        fetch_emoji()
    assert not (own_cache / "evil.webp").exists()  # where the member points, from the unpacking folder
    assert [p.name for p in sources.iterdir()] == [EMOJI_TARBALL]


def _held_out_word(library) -> str:
    words = ["kazoo", "abacus", "yoyo", "whistle", "harmonica", "compass", "hourglass", "stapler", "thimble"]
    return next(w for w in words if is_validation_group(w, 0.2) and not _names_test_noun(library, w))


def _names_test_noun(library, word: str) -> bool:
    from ocplace.sim.corpus.selection import names_test_noun, test_nouns

    return bool(names_test_noun(word, test_nouns(library.objects.values())))


def test_a_recipe_renders_cut_outs_only_when_it_asks_and_never_a_held_out_category(tmp_path, own_cache, library):
    held = _held_out_word(library)
    source, stamps = tmp_path / "catalogues", tmp_path / "stamps"
    _catalogue(source, ["Blue box", f"Old {held}", "Red cushion"])
    _write_stamp(stamps / "household", "ring", _ring())
    _write_stamp(stamps / "household", "held", _ring(), f"A toy {held}.\n".encode())
    _write_stamp(stamps / "animals", "bear", _ring(), b"A teddy bear.\n")
    corpus = build_corpus(source, progress=False, cutouts=("stamps",), cutout_folders={"stamps": stamps})
    names = {a.human_name: a.name for a in corpus.assets.values()}
    drop, stamps_config = default_config().render, dataclasses.replace(default_config().render, cutouts=("stamps",))
    assert held in validation_groups(corpus, library, drop) == validation_groups(corpus, library, stamps_config)
    assert not set(training_pool(library, corpus, drop).objects) & set(corpus.cutouts)
    pool = training_pool(library, corpus, stamps_config).objects
    assert names["ring"] in pool and names["teddy bear"] in pool and names[f"toy {held}"] not in pool
    assert names["teddy bear"] in strict_drops(corpus, library)  # `strict` drops a cut-out named by a test noun
    strict = dataclasses.replace(stamps_config, protocol="strict")
    assert names["teddy bear"] not in training_pool(library, corpus, strict).objects
    assert "cutouts" not in serial.to_json(drop) and "cutouts" in serial.to_json(stamps_config)
    bare = build_corpus(source, progress=False, cutout_folders={"stamps": tmp_path / "absent"})
    with pytest.raises(TrainingError, match="corpus build --cutouts stamps"):
        training_pool(library, bare, stamps_config)
    emoji_config = dataclasses.replace(stamps_config, cutouts=("emoji",))
    with pytest.raises(TrainingError, match="corpus build --cutouts emoji"):  # its stamps do not count
        training_pool(library, corpus, emoji_config)


@pytest.mark.skipif(not DEFAULT_STAMPS.is_dir(), reason=f"Tux Paint's stamps are not installed: {STAMPS_INSTALL_HINT}")
def test_real_stamps_become_textured_cut_outs(tmp_path, own_cache, monkeypatch):
    stamps = tmp_path / "stamps"
    for relative in ("household/dishes/teapot", "food/fruit/apple_green", "sports/balls/tennis_ball"):
        found = sorted(DEFAULT_STAMPS.glob(f"**/{Path(relative).name}.png"))
        target = stamps / relative
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(found[0], target.with_suffix(".png"))
        shutil.copy(found[0].with_suffix(".txt"), target.with_suffix(".txt"))
    _catalogue(tmp_path / "catalogues", ["Blue box"])
    monkeypatch.setenv(STAMPS_ENV, os.fspath(stamps))
    corpus = build_corpus(tmp_path / "catalogues", progress=False, cutouts=("stamps",))
    assert sorted(corpus.assets[name].human_name for name in corpus.cutouts) == ["green apple", "teapot", "tennis ball"]
    for name in corpus.cutouts:
        texture = np.asarray(Image.open(corpus.assets[name].texture))
        assert texture.std(axis=(0, 1)).max() > 10  # the image, not a flat colour
