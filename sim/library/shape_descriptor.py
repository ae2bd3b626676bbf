"""Shape descriptors and mesh matching: a content check of an object's geometry that survives the conversions
between caches.

The library and the corpus convert their sources differently (other frames, sizes, welding, UV seams,
decimation, file layouts), so a hash of their files, or of their vertex lists, never matches even for the
same source mesh. Two steps instead (docs/corpus.md gives the measured margins):
- the descriptor: a few area-weighted moments of the surface, the same up to translation, uniform scale and
  any rotation or mirror; two within `TOLERANCE` (relative, every entry) may be one mesh. Cheap, written
  beside each converted model, but any two spheres (or discs) share it.
- `same_mesh`, for those pairs: the vertices of one lie on the other's, in units of the surface's RMS radius
  about its area centroid, under one of the 48 axis turns and mirrors (the frames conversion changes; a
  copy turned by another angle is not caught). Decimation keeps a subset of the original vertices, so a
  decimated copy matches too; two tessellations of one sphere do not.
"""

from __future__ import annotations

import itertools
import json
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from ocplace.sim.library.types import ObjectAsset
from ocplace.sim.trimesh_io import read_trimesh

DESCRIPTOR_FILE = "shape.json"  # written beside a converted model, so checks need not read its meshes
# Below this many faces a mesh is a primitive-like shape (a box, a slab) that distinct models share by
# construction: no descriptor, so equal boxes are never called a copy.
MIN_FACES = 64
TOLERANCE = 0.05  # a copy decimated to half its faces moved its descriptor by up to 0.025 (docs/corpus.md)
MATCH_DISTANCE = 5e-3  # of the RMS radius, after the refit: float rounding, decimation's moved vertices
MATCH_SHARE = 0.95
MATCH_SAMPLE = 256
_REFITS = 3  # least-squares scale and offset to the nearest vertices, then nearest again
_MAX_REFIT = 0.05  # a refit that rescales more is collapsing the points, not aligning a copy


def _surface(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """`(3 * num_faces, 3)` edge midpoints with their area weights (exact for second moments) and the area."""
    corners = np.asarray(vertices, np.float64)[faces]  # (num_faces, 3, 3)
    areas = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    total = float(areas.sum())
    samples = np.concatenate([(corners[:, k] + corners[:, (k + 1) % 3]) / 2 for k in range(3)])
    return samples, np.tile(areas / max(total, 1e-300), 3) / 3.0, total


def _frame(samples: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, float]:
    """The area centroid and the RMS distance to it."""
    centre = weights @ samples
    offsets = samples - centre
    return centre, float(np.sqrt(weights @ np.einsum("ij,ij->i", offsets, offsets)))


def shape_descriptor(vertices: np.ndarray, faces: np.ndarray) -> tuple[float, ...]:
    """Seven scale-free numbers of the triangle surface `(num_vertices, 3)`, `(num_faces, 3)`, in units of its
    RMS distance to the area centroid: area, the three principal second moments, and the mean, third and
    fourth moments of the distance to the centroid; () when fewer than `MIN_FACES` faces or no area."""
    faces = np.asarray(faces, np.int64).reshape(-1, 3)
    if len(faces) < MIN_FACES:
        return ()
    samples, weights, total = _surface(vertices, faces)
    centre, scale = _frame(samples, weights)
    if total <= 0.0 or scale <= 0.0:
        return ()
    unit = (samples - centre) / scale
    moments = np.sort(np.linalg.eigvalsh((unit * weights[:, None]).T @ unit))
    radius = np.linalg.norm(unit, axis=1)
    radial = [float(weights @ radius**k) for k in (1, 3, 4)]
    return (total / scale**2, *map(float, moments), *radial)


def same_shape(a: tuple[float, ...], b: tuple[float, ...]) -> bool:
    """Whether two descriptors are one shape (an empty one is never anything's)."""
    if not a or len(a) != len(b):
        return False
    a_, b_ = np.asarray(a), np.asarray(b)
    return bool(np.all(np.abs(a_ - b_) <= TOLERANCE * np.maximum(np.abs(a_), np.abs(b_))))


def _joined(meshes) -> tuple[np.ndarray, np.ndarray]:
    """`(vertices, faces)` pairs as one mesh."""
    offsets = np.cumsum([0] + [len(vertices) for vertices, _ in meshes])
    vertices = np.concatenate([np.asarray(v, np.float64).reshape(-1, 3) for v, _ in meshes])
    faces = np.concatenate([np.asarray(f, np.int64).reshape(-1, 3) + offset for (_, f), offset in zip(meshes, offsets)])
    return vertices, faces


def mesh_descriptor(meshes) -> tuple[float, ...]:
    """The descriptor of `(vertices, faces)` pairs taken as one surface."""
    return shape_descriptor(*_joined(meshes))


def _meshes(asset: ObjectAsset) -> list[tuple[np.ndarray, np.ndarray]]:
    loaded = [read_trimesh(part.mesh, skip_materials=True) for part in asset.visual_parts]
    return [(np.asarray(mesh.vertices), np.asarray(mesh.faces)) for mesh in loaded]


def normalised_vertices(meshes) -> np.ndarray:
    """`(num_vertices, 3)` of `(vertices, faces)` pairs, about the surface's area centroid, in its RMS radius."""
    vertices, faces = _joined(meshes)
    centre, scale = _frame(*_surface(vertices, faces)[:2])
    return (vertices - centre) / max(scale, 1e-300)


def same_mesh(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether `normalised_vertices` `a` and `b` are one mesh: under one of the 48 axis turns and mirrors, and after
    refitting scale and offset to the nearest vertices (a decimated copy's centroid moves), `MATCH_SHARE` of (a
    sample of) the smaller set's vertices lie within `MATCH_DISTANCE` of the larger's."""
    few, many = sorted((np.asarray(a), np.asarray(b)), key=len)
    if len(few) == 0:
        return False
    sample = few[np.linspace(0, len(few) - 1, min(MATCH_SAMPLE, len(few))).astype(int)]
    tree = cKDTree(many)
    for axes in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            if _on_surface(sample[:, axes] * np.asarray(signs), many, tree):
                return True
    return False


def _on_surface(points: np.ndarray, vertices: np.ndarray, tree: cKDTree) -> bool:
    total_scale = 1.0
    for _ in range(_REFITS):
        _, nearest = tree.query(points)
        targets = vertices[nearest]
        centred, target_centred = points - points.mean(axis=0), targets - targets.mean(axis=0)
        scale = float(np.sum(centred * target_centred) / max(float(np.sum(centred * centred)), 1e-300))
        total_scale *= scale
        points = scale * centred + targets.mean(axis=0)
    if abs(total_scale - 1.0) > _MAX_REFIT:  # both are in units of their RMS radius: a copy needs no rescaling
        return False
    distances, _ = tree.query(points, distance_upper_bound=MATCH_DISTANCE)
    return bool(np.mean(distances <= MATCH_DISTANCE) >= MATCH_SHARE)


def asset_vertices(asset: ObjectAsset) -> np.ndarray:
    """`normalised_vertices` of every visual mesh of `asset`."""
    return normalised_vertices(_meshes(asset))


def write_descriptor(directory: Path, meshes) -> None:
    """Writes `DESCRIPTOR_FILE` of `(vertices, faces)` pairs into a model folder being converted."""
    (directory / DESCRIPTOR_FILE).write_text(json.dumps(mesh_descriptor(meshes)) + "\n")


def asset_descriptor(asset: ObjectAsset) -> tuple[float, ...]:
    """The descriptor of every visual mesh of `asset` together: its `DESCRIPTOR_FILE` where conversion wrote
    one, otherwise computed from the meshes (a cache converted before descriptors)."""
    written = asset.directory / DESCRIPTOR_FILE
    if written.is_file():
        return tuple(float(x) for x in json.loads(written.read_text()))
    return mesh_descriptor(_meshes(asset))
