"""Shared test fixtures."""

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
def arena(library):
    from ocplace.sim.mujoco_backend import MujocoScenes

    with MujocoScenes.from_library(library) as scenes:
        yield scenes
