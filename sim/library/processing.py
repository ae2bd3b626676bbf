"""Geometry and texture processing: pose, size, decimation, convex decomposition, mass.

Pure functions on arrays and images; no files.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import trimesh
from PIL import Image
from scipy.spatial.transform import Rotation

from ocplace.errors import AssetBuildError
from ocplace.sim.library.config import CoacdSettings
from ocplace.sim.library.meshes import TexturedMesh
from ocplace.sim.vectors import vec3

_WELD_DECIMALS = 7  # positions in metres (0.1 um) and UVs: merges only exact duplicates
_MIN_HULL_VOLUME = 1e-9  # m^3; coacd can emit slivers that MuJoCo rejects
_MIN_MASS = 0.01  # kg; lighter bodies chatter on contact at the usual time steps


@dataclasses.dataclass(frozen=True)
class Hull:
    vertices: np.ndarray  # (num_vertices, 3)
    faces: np.ndarray  # (num_faces, 3)


@dataclasses.dataclass(frozen=True)
class MassProperties:
    mass: float  # kg
    center_of_mass: np.ndarray  # (3,)
    inertia: np.ndarray  # (3, 3) about the centre of mass, kg m^2


def orient(mesh: TexturedMesh, scale, source_rotation: np.ndarray, turns) -> TexturedMesh:
    """Scales per mesh axis, then applies the source's rotation and the metadata turns."""
    rotation = source_rotation
    for axis, degrees in turns:
        rotation = Rotation.from_euler(axis, degrees, degrees=True).as_matrix() @ rotation
    vertices = (mesh.vertices * np.asarray(scale, np.float64)) @ rotation.T
    faces = mesh.faces
    if np.linalg.det(rotation * np.asarray(scale)) < 0:  # a mirror flips the winding
        faces = faces[:, ::-1]
    return dataclasses.replace(mesh, vertices=vertices, faces=faces)


def weld(mesh: TexturedMesh) -> TexturedMesh:
    """Merges vertices equal in position and UV (a triangle soup becomes a connected mesh)."""
    keys = mesh.vertices if mesh.uv is None else np.column_stack([mesh.vertices, mesh.uv])
    _, first, inverse = np.unique(np.round(keys, _WELD_DECIMALS), axis=0, return_index=True, return_inverse=True)
    faces = inverse.reshape(-1)[mesh.faces]
    faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])]
    uv = None if mesh.uv is None else mesh.uv[first]
    return dataclasses.replace(mesh, vertices=mesh.vertices[first], faces=faces, uv=uv)


def decimate(mesh: TexturedMesh, max_faces: int) -> TexturedMesh:
    """Quadric decimation to at most `max_faces`, carrying UVs along.

    Every surviving vertex is moved back onto the original vertex (among those collapsed into
    it) nearest to the optimiser's position, and takes that vertex's UV: the surface never
    leaves the original one (the optimiser can throw a vertex far off on ill-conditioned
    quadrics), and vertices split at UV seams keep each collapse inside one UV chart.
    """
    if len(mesh.faces) <= max_faces:
        return mesh
    import fast_simplification  # heavy native import, only when needed

    points = np.ascontiguousarray(mesh.vertices, np.float64)
    triangles = np.ascontiguousarray(mesh.faces, np.int32)
    _, _, collapses = fast_simplification.simplify(points, triangles, target_count=max_faces, return_collapses=True)
    optimised, faces, mapping = fast_simplification.replay_simplification(
        points.astype(np.float32), triangles, collapses
    )
    kept = mapping >= 0
    source = np.flatnonzero(kept)
    target = mapping[kept]
    distance = np.linalg.norm(points[source] - np.asarray(optimised)[target], axis=1)
    order = np.lexsort((distance, target))
    first = np.unique(target[order], return_index=True)[1]
    representative = np.zeros(len(optimised), np.int64)
    representative[target[order][first]] = source[order][first]
    uv = None if mesh.uv is None else mesh.uv[representative]
    return dataclasses.replace(mesh, vertices=points[representative], faces=np.asarray(faces, np.int64), uv=uv)


def rest_on_table(mesh: TexturedMesh) -> TexturedMesh:
    """Base on z = 0, axis-aligned box centred on x = y = 0."""
    low, high = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
    offset = np.array([(low[0] + high[0]) / 2, (low[1] + high[1]) / 2, low[2]])
    return dataclasses.replace(mesh, vertices=mesh.vertices - offset)


def extents(vertices: np.ndarray) -> tuple[float, float, float]:
    return vec3(vertices.max(axis=0) - vertices.min(axis=0))


def prepare_texture(image: Image.Image, max_px: int, tint=None) -> Image.Image:
    """Shrinks to at most `max_px` on the long side; optionally recolours (grey level x tint)."""
    if tint is not None:
        grey = np.asarray(image.convert("L"), np.float64) / 255.0
        grey = np.clip(grey / max(np.percentile(grey, 99), 1e-3), 0.0, 1.0)
        image = Image.fromarray(np.uint8(np.round(grey[..., None] * np.asarray(tint) * 255)), "RGB")
    if max(image.size) > max_px:
        ratio = max_px / max(image.size)
        width, height = (max(1, round(s * ratio)) for s in image.size)
        image = image.resize((width, height), Image.Resampling.LANCZOS)
    return image


def collision_input(mesh: TexturedMesh, max_faces: int) -> tuple[trimesh.Trimesh, bool]:
    """The shape handed to coacd, and whether it is a closed manifold.

    Positions only (UV seams closed), reduced to about `max_faces`. A closed input lets coacd
    skip its own remeshing, which turns a small mesh into tens of thousands of triangles and
    dominates its run time. Quadric decimation usually keeps a closed mesh closed; where it
    does not, manifold3d's simplification (which always does) is the fallback.
    """
    shape = weld(dataclasses.replace(mesh, uv=None, texture=None))
    decimated = decimate(shape, max_faces)
    reduced = trimesh.Trimesh(decimated.vertices, decimated.faces, process=True)
    if reduced.is_watertight:
        return reduced, True
    closed = _simplify_closed(shape, max_faces)
    if closed is not None:
        return closed, True
    return reduced, False


def _simplify_closed(shape: TexturedMesh, max_faces: int) -> trimesh.Trimesh | None:
    import manifold3d

    solid = manifold3d.Manifold(
        manifold3d.Mesh(
            vert_properties=np.asarray(shape.vertices, np.float32),
            tri_verts=np.asarray(shape.faces, np.uint32),
        )
    )
    if solid.status() != manifold3d.Error.NoError or solid.num_tri() == 0:
        return None
    tolerance = 1e-3 * float(np.ptp(shape.vertices, axis=0).max())
    while solid.num_tri() > max_faces:
        solid = solid.simplify(tolerance)
        tolerance *= 2.0
    out = solid.to_mesh()
    result = trimesh.Trimesh(out.vert_properties[:, :3], out.tri_verts, process=True)
    return result if result.is_watertight else None


def is_nearly_convex(shape: trimesh.Trimesh, min_ratio: float) -> bool:
    """Whether the shape fills at least `min_ratio` of its convex hull (volume)."""
    hull_volume = shape.convex_hull.volume
    return hull_volume > 0 and abs(shape.volume) / hull_volume >= min_ratio


def decompose(shape: trimesh.Trimesh, closed: bool, settings: CoacdSettings) -> list[Hull]:
    """Convex pieces of `shape`: coacd's cut and merge, then a cheap greedy merge to the cap.

    coacd's capped merge (`max_convex_hull`) compares every pair with sampled distances and
    takes minutes when the cut yields hundreds of pieces; merging by least added hull volume
    among neighbours takes about a second.
    """
    import coacd  # native library, imported where it runs

    coacd.set_log_level("error")
    parts = coacd.run_coacd(
        coacd.Mesh(shape.vertices, shape.faces),
        threshold=settings.threshold,
        max_convex_hull=-1,
        preprocess_mode="off" if closed else "on",
        preprocess_resolution=settings.preprocess_resolution,
        resolution=settings.resolution,
        mcts_nodes=settings.mcts_nodes,
        mcts_iterations=settings.mcts_iterations,
        mcts_max_depth=settings.mcts_max_depth,
        decimate=True,
        max_ch_vertex=settings.max_ch_vertex,
        seed=settings.seed,
    )
    points = [np.asarray(vertices, np.float64) for vertices, _ in parts]
    points = merge_hulls([p for p in points if _hull_volume(p) > _MIN_HULL_VOLUME], settings.max_convex_hull)
    hulls = [h for h in (_convex_hull(p) for p in points) if h is not None]
    if not hulls:  # nothing usable: one hull of the whole shape
        hull = _convex_hull(shape.vertices)
        if hull is None:
            raise AssetBuildError("the collision shape has no volume")
        hulls = [hull]
    return hulls


def convex_hull(shape: trimesh.Trimesh) -> list[Hull]:
    hull = _convex_hull(shape.vertices)
    if hull is None:
        raise AssetBuildError("the collision shape has no volume")
    return [hull]


def _hull_volume(points: np.ndarray) -> float:
    from scipy.spatial import ConvexHull, QhullError

    try:
        return float(ConvexHull(points).volume)
    except (QhullError, ValueError):
        return 0.0


def _hull_points(points: np.ndarray) -> np.ndarray:
    from scipy.spatial import ConvexHull

    return points[ConvexHull(points).vertices]


def merge_hulls(pieces: list[np.ndarray], max_count: int) -> list[np.ndarray]:
    """Greedily merges the pair whose joint hull adds least volume until `max_count` remain.

    `pieces`: point sets `(num_points, 3)`, one per convex piece. Only pieces whose boxes
    (grown by 5% of the object's size) touch are paired, which keeps this near-linear.
    """
    pieces = [_hull_points(p) for p in pieces]
    if len(pieces) <= max_count:
        return pieces
    margin = 0.05 * float(np.ptp(np.vstack(pieces), axis=0).max())
    volumes = [_hull_volume(p) for p in pieces]
    boxes = [(p.min(axis=0) - margin, p.max(axis=0) + margin) for p in pieces]

    def touching(a, b):
        return bool(np.all(boxes[a][0] <= boxes[b][1]) and np.all(boxes[b][0] <= boxes[a][1]))

    def pair_cost(a, b):
        return _hull_volume(np.vstack([pieces[a], pieces[b]])) - volumes[a] - volumes[b]

    alive = set(range(len(pieces)))
    cost = {(a, b): pair_cost(a, b) for a in alive for b in alive if a < b and touching(a, b)}
    while len(alive) > max_count:
        if not cost:  # no touching pieces left: allow any pair
            cost = {(a, b): pair_cost(a, b) for a in alive for b in alive if a < b}
        a, b = min(cost, key=lambda pair: cost[pair])
        pieces[a] = _hull_points(np.vstack([pieces[a], pieces[b]]))
        volumes[a] = _hull_volume(pieces[a])
        boxes[a] = (np.minimum(boxes[a][0], boxes[b][0]), np.maximum(boxes[a][1], boxes[b][1]))
        alive.discard(b)
        cost = {k: v for k, v in cost.items() if a not in k and b not in k}
        for c in alive - {a}:
            if touching(a, c):
                cost[min(a, c), max(a, c)] = pair_cost(min(a, c), max(a, c))
    return [pieces[k] for k in sorted(alive)]


def _convex_hull(points: np.ndarray) -> Hull | None:
    try:
        hull = trimesh.convex.convex_hull(points)
    except Exception:  # qhull raises its own error types for flat or tiny point sets
        return None
    if hull.volume < _MIN_HULL_VOLUME:
        return None
    return Hull(np.asarray(hull.vertices), np.asarray(hull.faces))


def mass_properties(hulls: list[Hull], density: float) -> MassProperties:
    """Uniform density over the hulls (overlaps counted twice), at least `_MIN_MASS`."""
    hull_masses, centres, inertias = [], [], []
    for hull in hulls:
        mesh = trimesh.Trimesh(hull.vertices, hull.faces, process=False)
        mesh.density = density
        hull_masses.append(mesh.mass)
        centres.append(mesh.center_mass)
        inertias.append(mesh.moment_inertia)
    masses = np.asarray(hull_masses)
    mass = float(masses.sum())
    centre = (masses[:, None] * np.asarray(centres)).sum(axis=0) / mass
    inertia = np.zeros((3, 3))
    for m, c, i in zip(masses, centres, inertias):
        d = c - centre
        inertia += i + m * (np.dot(d, d) * np.eye(3) - np.outer(d, d))  # parallel axis
    boost = max(1.0, _MIN_MASS / mass)
    return MassProperties(mass * boost, centre, inertia * boost)
