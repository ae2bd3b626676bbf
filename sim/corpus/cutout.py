"""A named 2-D image as a thin textured cut-out: its alpha mask, triangulated, extruded into a prism lying flat,
textured from above by a planar projection of the image (docs/offline_backbone.md, "Cut-outs").

The top face is a Delaunay triangulation of points on the mask's outline and inside it, keeping the triangles
whose centre lies on the mask; the side walls stand on the boundary edges of that triangle set, so the prism
is closed whatever the outline's concavities and holes. The top camera sees the image as a flat object.
"""

from __future__ import annotations

import cv2
import numpy as np
from PIL import Image
from scipy.spatial import Delaunay

from ocplace.errors import CorpusError
from ocplace.sim.library.meshes import TexturedMesh

SIZE_CM = (15.0, 15.0, 1.0)  # every cut-out's longest side, again, and thickness: an image carries no size
MIN_SIDE_PX = 32  # a smaller stamp is an icon, not an object
ALPHA_CUT = 128
MIN_PART_SHARE = 0.02  # mask pieces smaller than this share of the largest are specks, dropped
GRID_POINTS = 24  # interior points per side of the mask's box: the outline carries the detail
OUTLINE_TOLERANCE = 0.004  # of the box's longest side: how far the simplified outline may stray from the mask's


def mask_of(image: Image.Image) -> tuple[np.ndarray, np.ndarray]:
    """The RGB pixels and the opaque mask of `image`, cropped to the mask's box: `(h, w, 3)` uint8, `(h, w)` bool.

    CorpusError for an image without alpha, an empty mask, or a mask box under `MIN_SIDE_PX` on its longest side.
    """
    if "A" not in image.getbands() and "transparency" not in image.info:
        raise CorpusError(f"the image has no alpha channel (mode {image.mode})")
    rgba = np.asarray(image.convert("RGBA"))
    mask = _without_specks(rgba[..., 3] >= ALPHA_CUT)
    if not mask.any():
        raise CorpusError("the image's alpha mask is empty")
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    box = (slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1))
    if max(mask[box].shape) < MIN_SIDE_PX:
        raise CorpusError(f"the opaque part is {mask[box].shape[1]} x {mask[box].shape[0]} px, under {MIN_SIDE_PX} px")
    return np.ascontiguousarray(rgba[box][..., :3]), mask[box]


def _without_specks(mask: np.ndarray) -> np.ndarray:
    count, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    if count <= 1:
        return mask
    areas = stats[1:, cv2.CC_STAT_AREA]
    keep = np.flatnonzero(areas >= MIN_PART_SHARE * areas.max()) + 1
    return np.isin(labels, keep)


def filled_texture(rgb: np.ndarray, mask: np.ndarray) -> Image.Image:
    """The image with its transparent pixels filled from the opaque ones nearby, so texture filtering at the
    outline never samples the background colour."""
    filled = cv2.inpaint(rgb, (~mask).astype(np.uint8), 3, cv2.INPAINT_TELEA)
    return Image.fromarray(filled, "RGB")


def _points(mask: np.ndarray) -> np.ndarray:
    """Outline points (simplified) and a sparse interior grid, `(n, 2)` float in pixels (x, y)."""
    height, width = mask.shape
    padded = np.pad(mask, 1).astype(np.uint8)
    contours, _ = cv2.findContours(padded, cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)
    tolerance = OUTLINE_TOLERANCE * max(height, width)
    outline = np.concatenate([cv2.approxPolyDP(c, tolerance, True)[:, 0, :] for c in contours]).astype(np.float64) - 1.0
    spacing = max(height, width) / GRID_POINTS
    ys, xs = np.mgrid[spacing / 2 : height : spacing, spacing / 2 : width : spacing]
    grid = np.stack([xs.ravel(), ys.ravel()], axis=1)
    grid = grid[mask[grid[:, 1].astype(int), grid[:, 0].astype(int)]]
    # Pixel centres: an outline pixel's centre lies on the mask, so the triangles between outline points do.
    return np.unique(np.concatenate([outline, grid]) + 0.5, axis=0)


def _top_triangles(points: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Delaunay triangles whose centre lies on the mask, counter-clockwise in (x, -y), `(m, 3)` int."""
    triangles = Delaunay(points).simplices
    centres = points[triangles].mean(axis=1)
    inside = mask[
        np.clip(centres[:, 1].astype(int), 0, mask.shape[0] - 1),
        np.clip(centres[:, 0].astype(int), 0, mask.shape[1] - 1),
    ]
    triangles = triangles[inside]
    a, b, c = (points[triangles[:, k]] for k in range(3))
    # Image y points down: counter-clockwise seen from +z in the object frame is clockwise in pixels.
    cross = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    return np.where((cross > 0)[:, None], triangles[:, ::-1], triangles)


def _boundary_edges(triangles: np.ndarray) -> np.ndarray:
    """Directed edges used by one triangle only, in that triangle's order, `(k, 2)` int."""
    edges = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    undirected = np.sort(edges, axis=1)
    _, inverse, counts = np.unique(undirected, axis=0, return_inverse=True, return_counts=True)
    return edges[counts[inverse.ravel()] == 1]


def cutout_mesh(mask: np.ndarray, texture: Image.Image, extent_m: float, thickness_m: float) -> TexturedMesh:
    """The prism of `mask` (`(h, w)` bool), its longest side `extent_m`, `thickness_m` thick, resting on z = 0
    and centred on x = y = 0, with planar UVs into `texture` (the image of the mask's box)."""
    height, width = mask.shape
    points = _points(mask)
    top = _top_triangles(points, mask)
    if len(top) == 0:
        raise CorpusError("the alpha mask leaves no triangle")
    used = np.unique(top)
    remap = np.full(len(points), -1)
    remap[used] = np.arange(len(used))
    pixels, top = points[used], remap[top]
    scale = extent_m / max(height, width)
    xy = np.stack([(pixels[:, 0] - width / 2) * scale, (height / 2 - pixels[:, 1]) * scale], axis=1)
    uv = np.stack([pixels[:, 0] / width, 1.0 - pixels[:, 1] / height], axis=1)
    count = len(xy)
    vertices = np.concatenate(
        [np.column_stack([xy, np.full(count, thickness_m)]), np.column_stack([xy, np.zeros(count)])]
    )
    edges = _boundary_edges(top)
    walls = np.concatenate(
        [
            np.column_stack([edges[:, 1], edges[:, 0], edges[:, 0] + count]),
            np.column_stack([edges[:, 1], edges[:, 0] + count, edges[:, 1] + count]),
        ]
    )
    faces = np.concatenate([top, top[:, ::-1] + count, walls]).astype(np.int64)
    return TexturedMesh(vertices, faces, np.concatenate([uv, uv]), texture, (1.0, 1.0, 1.0, 1.0))
