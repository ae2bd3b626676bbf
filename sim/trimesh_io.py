"""Reading a mesh file as one `trimesh.Trimesh`, typed as one.

`trimesh.load` is typed as returning any geometry (a scene, a point cloud); with `force="mesh"` it returns a
mesh, and this says so once, checked, for the type checker and the reader.
"""

from __future__ import annotations

from pathlib import Path

import trimesh


def read_trimesh(path: str | Path, skip_materials: bool = False) -> trimesh.Trimesh:
    """The mesh at `path`, unprocessed (vertex order kept); ValueError when it holds no triangle mesh."""
    loaded = trimesh.load(path, force="mesh", process=False, skip_materials=skip_materials)
    if not isinstance(loaded, trimesh.Trimesh):
        raise ValueError(f"{path} holds no triangle mesh ({type(loaded).__name__})")
    return loaded
