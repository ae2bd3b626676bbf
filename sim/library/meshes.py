"""Loading a source's visual mesh and texture into one in-memory form."""

from __future__ import annotations

import dataclasses

import numpy as np
import trimesh
from PIL import Image

from ocplace.errors import AssetBuildError, MshFormatError
from ocplace.sim.library.msh import read_msh
from ocplace.sim.library.sources import SourceFiles


@dataclasses.dataclass(frozen=True)
class TexturedMesh:
    """A triangle mesh with optional per-vertex UVs (OBJ convention: v from the bottom)."""

    vertices: np.ndarray  # (num_vertices, 3) float64
    faces: np.ndarray  # (num_faces, 3) int64
    uv: np.ndarray | None  # (num_vertices, 2) float64
    texture: Image.Image | None  # RGB
    rgba: tuple[float, float, float, float]


def _read_geometry(files: SourceFiles) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    if files.mesh.suffix == ".msh":
        msh = read_msh(files.mesh)
        uv = msh.texcoords.astype(np.float64) if msh.texcoords is not None else None
        return msh.vertices.astype(np.float64), msh.faces, uv
    loaded = trimesh.load(files.mesh, force="mesh", process=False)
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise AssetBuildError(f"{files.mesh} holds no triangles")
    uv = getattr(loaded.visual, "uv", None)
    uv = np.asarray(uv, dtype=np.float64) if uv is not None and len(uv) == len(loaded.vertices) else None
    return np.asarray(loaded.vertices, np.float64), np.asarray(loaded.faces, np.int64), uv


def load_mesh(files: SourceFiles) -> TexturedMesh:
    """Reads mesh and texture; raises `AssetBuildError` for missing, corrupt or empty files."""
    try:
        vertices, faces, uv = _read_geometry(files)
    except (OSError, ValueError, IndexError, MshFormatError) as error:
        raise AssetBuildError(f"cannot read mesh {files.mesh}: {error}") from error
    if len(faces) == 0 or not np.isfinite(vertices).all():
        raise AssetBuildError(f"{files.mesh}: no triangles or non-finite vertices")
    if uv is not None and files.uv_origin == "top":
        uv = np.column_stack([uv[:, 0], 1.0 - uv[:, 1]])
    texture = None
    if files.texture is not None:
        if uv is None:
            raise AssetBuildError(f"{files.mesh} has a texture but no texture coordinates")
        try:
            with Image.open(files.texture) as image:
                texture = image.convert("RGB")
        except OSError as error:
            raise AssetBuildError(f"cannot read texture {files.texture}: {error}") from error
    return TexturedMesh(vertices, faces, uv if texture is not None else None, texture, files.rgba)
