"""ocplace: object-centric, language-conditioned object placement."""

import os

# MuJoCo picks its OpenGL backend when it is first imported; without this default it would try
# GLFW, which needs a display. `make` exports osmesa instead on machines without EGL.
os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])


def _version() -> str:
    """The installed package's version (a wheel's, or an editable install's), else the source tree's."""
    from importlib import metadata

    try:
        return metadata.version("ocplace")
    except metadata.PackageNotFoundError:  # imported from a source tree that was never installed
        return "0.1.0"


__version__ = _version()
