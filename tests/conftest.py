"""Shared test fixtures."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")
