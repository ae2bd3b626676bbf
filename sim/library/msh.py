"""Reader for MuJoCo's legacy binary `.msh` mesh format.

Layout: four int32 counts (nvertex, nnormal, ntexcoord, nface), then float32 positions
`(nvertex, 3)`, float32 normals `(nnormal, 3)`, float32 texcoords `(ntexcoord, 2)` and int32
faces `(nface, 3)`. Texture coordinates are stored as MuJoCo uses them, with v measured from
the top of the image; OBJ files measure v from the bottom.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from ocplace.errors import MshFormatError

_HEADER_BYTES = 16


@dataclasses.dataclass(frozen=True)
class MshMesh:
    vertices: np.ndarray  # (num_vertices, 3) float32
    normals: np.ndarray | None  # (num_vertices, 3) float32
    texcoords: np.ndarray | None  # (num_vertices, 2) float32, MuJoCo convention
    faces: np.ndarray  # (num_faces, 3) int64


def parse_msh(data: bytes) -> MshMesh:
    """Decodes `.msh` bytes; raises `MshFormatError` on anything inconsistent."""
    if len(data) < _HEADER_BYTES:
        raise MshFormatError(f"{len(data)} bytes is too short for a .msh header")
    nvertex, nnormal, ntexcoord, nface = (int(n) for n in np.frombuffer(data[:16], "<i4"))
    if min(nvertex, nnormal, ntexcoord, nface) < 0 or nvertex < 3:
        raise MshFormatError(f"bad counts {(nvertex, nnormal, ntexcoord, nface)}")
    sizes = (3 * nvertex, 3 * nnormal, 2 * ntexcoord, 3 * nface)
    expected = _HEADER_BYTES + 4 * sum(sizes)
    if len(data) != expected:
        raise MshFormatError(f"expected {expected} bytes from the header, found {len(data)}")
    if nnormal not in (0, nvertex) or ntexcoord not in (0, nvertex):
        raise MshFormatError("normals and texcoords must be absent or one per vertex")
    offsets = np.cumsum((_HEADER_BYTES,) + tuple(4 * s for s in sizes))
    positions = np.frombuffer(data, "<f4", sizes[0], offsets[0]).reshape(-1, 3)
    normals = np.frombuffer(data, "<f4", sizes[1], offsets[1]).reshape(-1, 3)
    texcoords = np.frombuffer(data, "<f4", sizes[2], offsets[2]).reshape(-1, 2)
    if nface:
        faces = np.frombuffer(data, "<i4", sizes[3], offsets[3]).reshape(-1, 3).astype(np.int64)
    else:  # MuJoCo reads a face-less .msh as a triangle soup
        if nvertex % 3:
            raise MshFormatError("a face-less .msh needs a multiple of 3 vertices")
        faces = np.arange(nvertex, dtype=np.int64).reshape(-1, 3)
    if faces.min() < 0 or faces.max() >= nvertex:
        raise MshFormatError("face index out of range")
    if not np.isfinite(positions).all():
        raise MshFormatError("non-finite vertex positions")
    return MshMesh(
        vertices=positions.copy(),
        normals=normals.copy() if nnormal else None,
        texcoords=texcoords.copy() if ntexcoord else None,
        faces=faces,
    )


def read_msh(path: str | Path) -> MshMesh:
    return parse_msh(Path(path).read_bytes())
