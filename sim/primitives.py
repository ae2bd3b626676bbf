"""Named primitive shapes (box, cylinder, sphere, ...) as arena objects for backbone pretraining.

A primitive is an untextured `ObjectAsset` whose meshes are generated here, so `MujocoScenes` drops,
settles and renders it exactly like a library object. It never enters the object library: its
`split` is `PRIMITIVE_SPLIT`, and it has no standalone MJCF or URDF (it lives only in an arena).
Meshes follow the library's frame: base on z = 0, AABB centred on x = y = 0, resting pose +z up.
"""

from __future__ import annotations

import dataclasses
import io
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import trimesh

from ocplace.errors import SceneError
from ocplace.paths import write_text_atomic
from ocplace.sim.library.types import ObjectAsset
from ocplace.sim.vectors import vec3
from ocplace.vocabulary import SHAPES, SIZES

PRIMITIVE_SPLIT = "primitive"
DENSITY = 400.0  # kg/m^3: between wood and hollow plastic, like the library's objects
NEUTRAL_RGBA = (0.7, 0.7, 0.7, 1.0)  # until a scene paints it
RING_PIECES = 12  # convex sectors of the ring (a torus is not convex; MuJoCo collides hulls)


@dataclasses.dataclass(frozen=True)
class Primitive:
    """One shape at one size; `width` (m) is its largest horizontal extent."""

    shape: str
    size: str
    width: float

    @property
    def name(self) -> str:
        return f"primitive_{self.shape}_{self.size}"


def primitive_set(shapes: Sequence[str], widths: Sequence[float]) -> tuple[Primitive, ...]:
    """Every shape at each of the small, medium and large `widths`."""
    unknown = [shape for shape in shapes if shape not in SHAPES]
    if unknown or len(widths) != len(SIZES):
        raise SceneError(
            f"primitives need shapes among {SHAPES} (got unknown {unknown}) and {len(SIZES)} widths (got {len(widths)})"
        )
    return tuple(Primitive(shape, size, float(width)) for shape in shapes for size, width in zip(SIZES, widths))


def _rest_on_origin(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    low, high = mesh.bounds
    mesh.apply_translation([-(low[0] + high[0]) / 2, -(low[1] + high[1]) / 2, -low[2]])
    return mesh


def _pyramid(width: float) -> trimesh.Trimesh:
    half = 0.45 * width
    corners = [[x, y, 0.0] for x in (-half, half) for y in (-half, half)]
    return trimesh.convex.convex_hull(np.array(corners + [[0.0, 0.0, 0.7 * width]]))


def _capsule(width: float) -> trimesh.Trimesh:
    radius = 0.2 * width
    mesh = trimesh.creation.capsule(height=width - 2 * radius, radius=radius, count=[16, 16])
    return mesh.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))  # lying down


def _ring_size(width: float) -> tuple[float, float]:
    """Major and minor radius of the torus."""
    minor = 0.13 * width
    return width / 2 - minor, minor


def shape_mesh(shape: str, width: float) -> trimesh.Trimesh:
    """The visual mesh of `shape` at `width`, resting on z = 0."""
    builders = {
        "box": lambda w: trimesh.creation.box((0.8 * w,) * 3),
        "cylinder": lambda w: trimesh.creation.cylinder(w / 2, 0.9 * w, sections=32),
        "sphere": lambda w: trimesh.creation.icosphere(3, w / 2),
        "cone": lambda w: trimesh.creation.cone(w / 2, w, sections=32),
        "ring": lambda w: trimesh.creation.torus(*_ring_size(w), major_sections=48, minor_sections=16),
        "disc": lambda w: trimesh.creation.cylinder(w / 2, 0.12 * w, sections=48),
        "capsule": _capsule,
        "pyramid": _pyramid,
    }
    return _rest_on_origin(builders[shape](width))


def convex_pieces(shape: str, mesh: trimesh.Trimesh, width: float) -> list[trimesh.Trimesh]:
    """Convex collision pieces: the mesh itself, or sectors of the tube for the ring."""
    if shape != "ring":
        return [mesh.convex_hull]
    major, minor = _ring_size(width)
    tube = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    circle = np.stack([major + minor * np.cos(tube), minor * (1 + np.sin(tube))], axis=1)  # (r, z), base on z = 0
    pieces = []
    for k in range(RING_PIECES):
        angles = 2 * np.pi * np.array([k, k + 1]) / RING_PIECES
        points = [[r * np.cos(a), r * np.sin(a), z] for a in angles for r, z in circle]
        pieces.append(trimesh.convex.convex_hull(np.array(points)))
    return pieces


def _obj_text(mesh: trimesh.Trimesh) -> str:
    buffer = io.StringIO()
    np.savetxt(buffer, mesh.vertices, fmt="v %.6f %.6f %.6f")
    np.savetxt(buffer, mesh.faces + 1, fmt="f %d %d %d")
    return buffer.getvalue()


def primitive_asset(primitive: Primitive, directory: Path) -> ObjectAsset:
    """Writes the primitive's meshes under `directory/<name>/` and returns its arena record."""
    folder = Path(directory) / primitive.name
    mesh = shape_mesh(primitive.shape, primitive.width)
    pieces = convex_pieces(primitive.shape, mesh, primitive.width)
    visual = folder / "visual.obj"
    write_text_atomic(visual, _obj_text(mesh))
    hulls = tuple(folder / f"hull_{i:03d}.obj" for i in range(len(pieces)))
    for path, piece in zip(hulls, pieces, strict=True):
        write_text_atomic(path, _obj_text(piece))
    return ObjectAsset(
        name=primitive.name,
        human_name=f"{primitive.size} {primitive.shape}",
        synonyms=(),
        category=primitive.shape,
        split=PRIMITIVE_SPLIT,
        source="ocplace:primitive",
        licence="generated",
        directory=folder,
        visual_mesh=visual,
        texture=None,
        rgba=NEUTRAL_RGBA,
        hulls=hulls,
        mjcf=Path(),
        urdf=Path(),  # arena-only: nothing loads a primitive on its own
        extents=vec3(mesh.extents),
        mass=DENSITY * sum(p.volume for p in pieces),
    )
