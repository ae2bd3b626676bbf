"""ocplace: object-centric, language-conditioned object placement."""

import os

# MuJoCo picks its OpenGL backend when it is first imported; without this default it would try
# GLFW, which needs a display. `make` exports osmesa instead on machines without EGL.
os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])

__version__ = "0.1.0"
