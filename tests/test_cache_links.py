"""Nothing is deleted or created outside the cache through a symbolic link planted in it (issue 43, defect 1):
the folders whose entries ocplace sweeps refuse to be links, a link inside them is removed as a link, and a
lock never creates a link's target. Real folders, the real library and corpus builds."""

from __future__ import annotations

import os
import shutil

import pytest
from test_corpus import _cube, _write_catalogue

from ocplace.errors import CacheError
from ocplace.paths import file_lock, remove_abandoned_tmp


def _keep(tmp_path):
    """A user's folder with a subfolder and a file, and what it holds."""
    keep = tmp_path / "keep"
    (keep / "sub").mkdir(parents=True)
    (keep / "sub" / "notes.txt").write_text("mine\n")
    return keep


def test_a_symlinked_tmp_is_refused_and_a_link_inside_it_is_removed_as_a_link(tmp_path):
    keep = _keep(tmp_path)
    (tmp_path / "cache").mkdir()
    tmp_root = tmp_path / "cache" / "tmp"
    tmp_root.symlink_to(keep)
    with pytest.raises(CacheError, match="is a symbolic link.*remove the link"):
        remove_abandoned_tmp(tmp_root)
    assert (keep / "sub" / "notes.txt").read_text() == "mine\n"
    tmp_root.unlink()
    tmp_root.mkdir()
    (tmp_root / "model.999999999.abc").symlink_to(keep)  # a dead build's name, pointing out
    (tmp_root / "model.999999998.def").mkdir()  # a dead build's real folder
    remove_abandoned_tmp(tmp_root)
    assert list(tmp_root.iterdir()) == [] and (keep / "sub" / "notes.txt").is_file()


def test_a_lock_never_creates_the_target_of_a_link(tmp_path):
    target = tmp_path / "features" / "batch.safetensors"
    target.parent.mkdir()
    elsewhere = tmp_path / "elsewhere" / "created"
    elsewhere.parent.mkdir()
    target.with_name(".batch.safetensors.lock").symlink_to(elsewhere)
    with pytest.raises(CacheError, match="symbolic link"), file_lock(target):
        pass
    assert not elsewhere.exists()
    with file_lock(tmp_path / "features" / "other.safetensors"):  # a plain lock still works
        assert (tmp_path / "features" / ".other.safetensors.lock").is_file()


def test_the_corpus_build_refuses_symlinked_models_and_tmp_folders(tmp_path, monkeypatch):
    from ocplace.sim.corpus.build import build_corpus
    from ocplace.sim.corpus.emoji import EMOJI_ENV
    from ocplace.sim.corpus.stamps import STAMPS_ENV

    cache = tmp_path / "cache"
    monkeypatch.setenv("OCPLACE_CACHE", str(cache))
    monkeypatch.setenv(STAMPS_ENV, str(tmp_path / "no-stamps"))
    monkeypatch.setenv(EMOJI_ENV, str(tmp_path / "no-emoji"))
    source = tmp_path / "catalogues"
    source.mkdir()
    _write_catalogue(source / "Test.sh3f", {"Sugar bowl": _cube("bowl")})
    corpus = build_corpus(source=source, progress=False)
    assert len(corpus.assets) == 1
    keep = _keep(tmp_path)
    for folder in ("models", "tmp"):
        real = cache / "corpus" / folder
        moved = tmp_path / f"moved-{folder}"
        if real.exists():
            shutil.move(real, moved)
        real.symlink_to(keep)
        with pytest.raises(CacheError, match=f"corpus/{folder} is a symbolic link"):
            build_corpus(source=source, progress=False)
        assert sorted(os.listdir(keep)) == ["sub"] and (keep / "sub" / "notes.txt").is_file()
        real.unlink()
        if moved.exists():
            shutil.move(moved, real)
    assert len(build_corpus(source=source, progress=False).assets) == 1  # links gone: builds as before


def test_the_library_build_refuses_a_symlinked_tmp(library, tmp_path, monkeypatch):
    """The issue's case: `ln -s keep $CACHE/library/tmp; ocplace assets build` removed `keep/sub`."""
    from ocplace.sim.library import build_library, default_config

    cache = tmp_path / "cache"
    shutil.copytree(library.root, cache / "library", copy_function=os.link, ignore=shutil.ignore_patterns("tmp"))
    keep = _keep(tmp_path)
    (cache / "library" / "tmp").symlink_to(keep)
    with pytest.raises(CacheError, match="library/tmp is a symbolic link"):
        build_library(default_config(), cache=cache, progress=False)
    assert (keep / "sub" / "notes.txt").read_text() == "mine\n"
