"""Shared test fixtures."""

import contextlib
import os
import shutil
import subprocess
from pathlib import Path

import pytest

import ocplace  # noqa: F401  (sets the headless OpenGL default before MuJoCo loads)


@pytest.fixture(scope="session")
def library():
    """The default object library, built into the cache on first use (`make test` builds it first)."""
    from ocplace.errors import LibraryNotBuilt
    from ocplace.sim.library import build_library, default_config, load_library

    try:
        return load_library()
    except LibraryNotBuilt:
        return build_library(default_config(), progress=False)


@pytest.fixture(scope="session")
def corpus():
    """The pretraining corpus, converted into the cache on first use (`make test` builds it first)."""
    from ocplace.sim.corpus.build import build_corpus

    return build_corpus(progress=False)


@pytest.fixture(scope="session")
def arena(library):
    from ocplace.sim.mujoco_backend import MujocoScenes

    with MujocoScenes.from_library(library) as scenes:
        yield scenes


@pytest.fixture(scope="session")
def smoke_dataset(tmp_path_factory, library):
    """The smoke benchmark (12 train scenes, 8 per test split), generated once per test session."""
    from ocplace.sim.dataset.config import smoke_config
    from ocplace.sim.dataset.job import generate_dataset

    out = tmp_path_factory.mktemp("smoke_dataset")
    generate_dataset(out, smoke_config(), progress=False)
    return out


@pytest.fixture(scope="session")
def tokenizer_dir(tmp_path_factory):
    """A tiny CLIP tokenizer's files (tests/tiny_clip.py)."""
    from tiny_clip import write_tokenizer

    directory = tmp_path_factory.mktemp("tokenizer")
    write_tokenizer(directory)
    return directory


@pytest.fixture(scope="session")
def tiny_backbone_spec(tmp_path_factory):
    """`offline:<dir>`: a randomly initialised smoke-size offline backbone saved to disk."""
    import jax

    from ocplace.models import offline_backbone as ob
    from ocplace.models import offline_config

    config = offline_config.smoke_config()
    params = ob.init_params(config, jax.random.key(0))
    directory = ob.save_backbone(
        tmp_path_factory.mktemp("tiny_backbone"), config, params, ob.FrozenTextTower.load(config.text_max_length).digest
    )
    return f"offline:{directory}"


@pytest.fixture(scope="session")
def trained_run(smoke_dataset, tiny_backbone_spec, tmp_path_factory):
    """`(run_dir, feature files)`: Ours trained at smoke size on the tiny backbone, in a cache of its own."""
    from ocplace.configs import smoke
    from ocplace.methods.contract import TrainContext
    from ocplace.methods.registry import method_specs

    cache = tmp_path_factory.mktemp("ours_cache")
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("OCPLACE_CACHE", str(cache))
        run = method_specs()["ours"].train(
            TrainContext(
                smoke_dataset,
                tiny_backbone_spec,
                tmp_path_factory.mktemp("ours") / "run",
                smoke.get_config().recipes["ours"],
                fraction=0.5,
                seed=3,
            )
        )
        features = sorted((cache / "features").glob("*.safetensors"))
    return run, features


# The cache folders a test's own cache borrows from the real one: built once, only read by the tests that borrow them.
_BORROWED_CACHE_FOLDERS = ("library", "sources", "corpus", "weights", "primitives", "compiled")


@pytest.fixture(scope="session")
def smoke_rows(smoke_dataset, tiny_backbone_spec, tmp_path_factory):
    """`{name: run directory}`: each registered row that learns, trained through its spec with the smoke recipe on
    the tiny backbone when first asked for (its shared inputs made first), in a cache of its own."""
    from lazy import Lazy

    from ocplace.configs import smoke
    from ocplace.methods.contract import TrainContext
    from ocplace.methods.registry import method_specs

    cache, recipes = tmp_path_factory.mktemp("rows_cache"), smoke.get_config().recipes

    def train(name):
        spec = method_specs()[name]
        context = TrainContext(smoke_dataset, tiny_backbone_spec, tmp_path_factory.mktemp(name), recipes.get(name))
        with pytest.MonkeyPatch.context() as patch:
            patch.setenv("OCPLACE_CACHE", str(cache))
            if spec.prepare is not None:
                spec.prepare(context)
            return spec.train(context)

    return Lazy(train)


@pytest.fixture
def borrowed_cache(tmp_path, monkeypatch):
    """A cache of the test's own, in this process and in the processes it starts, borrowing the built library,
    corpus and converted weights from the real cache: what the test makes (backbones, features) stays in it."""
    from ocplace.paths import cache_dir

    real, own = cache_dir(), tmp_path / "cache"
    own.mkdir()
    for name in _BORROWED_CACHE_FOLDERS:
        if (real / name).exists():
            (own / name).symlink_to(real / name)
    monkeypatch.setenv("OCPLACE_CACHE", str(own))
    return own


@pytest.fixture
def default_offline_backbone(borrowed_cache, tiny_backbone_spec):
    """Makes the bare spec `offline` (the default recipe's backbone) load the tiny backbone, in this process
    and in the processes it starts: a cache of the test's own, holding it where the default recipe's
    backbone is saved and borrowing the built library and corpus from the real cache."""
    from ocplace.models.offline_recipes import recipe_dir

    directory = recipe_dir("default")
    directory.parent.mkdir(parents=True)
    directory.symlink_to(tiny_backbone_spec.removeprefix("offline:"))
    return directory


@contextlib.contextmanager
def _tmpfs(folder: Path, options: str):
    """A small file system mounted on `folder`. Needs the right to mount (root in a container); else skips."""
    folder.mkdir()
    if (
        shutil.which("mount") is None
        or subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(folder)], capture_output=True).returncode
        != 0
    ):
        pytest.skip("cannot mount a file system here")
    try:
        yield folder
    finally:
        subprocess.run(["umount", str(folder)], check=True)


@pytest.fixture
def tmpfs():
    """`tmpfs(folder, options)`: a context manager mounting a small file system on `folder`."""
    return _tmpfs


@pytest.fixture
def read_only_dir(tmp_path):
    """A folder that cannot be written: mode 555, or for root (whom modes do not stop) a read-only mount."""
    folder = tmp_path / "read-only"
    if os.geteuid() != 0:
        folder.mkdir(mode=0o555)
        yield folder
        folder.chmod(0o755)
        return
    with _tmpfs(folder, "ro,size=64k"):
        yield folder


@pytest.fixture
def full_disk(tmp_path):
    """A 64 KiB file system, filled."""
    with _tmpfs(tmp_path / "small-disk", "size=64k") as mount:
        with contextlib.suppress(OSError), open(mount / "filler", "wb") as filler:
            filler.write(b"\0" * (1 << 20))
        yield mount
