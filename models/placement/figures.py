"""The paper's Fig. 5: placement densities over a top-down image (table region, one object
relation, a two-relation composition), with sampled points and the mode.

Works with any image and any world-to-pixel mapping (a `Camera` or a callable taking `(N, 3)`
world points on the table plane z = 0 and returning `(N, 2)` pixels (u right, v down)).
"""

from __future__ import annotations

import dataclasses
import itertools
import textwrap
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ocplace.errors import ConfigError, NoFeasiblePlacement
from ocplace.sim import metric, relations
from ocplace.sim.metric import Grid, GroundedTuple
from ocplace.vocabulary import FIGURE_FORMATS

PANEL_KINDS = ("table region", "one object relation", "two-relation composition")
MAX_DPI = 1200


@dataclasses.dataclass(frozen=True)
class FigureStyle:
    """How a figure is written: its file format (the path's suffix follows it) and, for PNG, its resolution."""

    format: str = "png"
    dpi: int = 150

    def validate(self) -> None:
        """ConfigError, before anything is drawn, for a format not in FIGURE_FORMATS or a dpi out of range."""
        if self.format not in FIGURE_FORMATS:
            raise ConfigError(f"figure format {self.format!r} is not one of {', '.join(FIGURE_FORMATS)}")
        if isinstance(self.dpi, bool) or not isinstance(self.dpi, int) or not 10 <= self.dpi <= MAX_DPI:
            raise ConfigError(f"--dpi must be a whole number from 10 to {MAX_DPI}, got {self.dpi!r}")


@dataclasses.dataclass(frozen=True)
class Panel:
    title: str
    heatmap: np.ndarray  # (nx, ny) density on `grid`
    samples: np.ndarray  # (N, 2) placements
    mode: np.ndarray  # (2,)
    references: np.ndarray  # (R, 2, 2) AABBs of the reference objects, outlined


def _as_mapping(world_to_pixel) -> Callable[[np.ndarray], np.ndarray]:
    return getattr(world_to_pixel, "world_to_pixel", world_to_pixel)


def _to_pixels(mapping, points_xy: np.ndarray) -> np.ndarray:
    points_xy = np.asarray(points_xy, dtype=float).reshape(-1, 2)
    points = np.concatenate([points_xy, np.zeros((len(points_xy), 1))], axis=1)
    return np.asarray(mapping(points), dtype=float).reshape(-1, 2)


def _outline(axis, mapping, box, **style) -> None:
    (x0, y0), (x1, y1) = box
    outline = _to_pixels(mapping, np.asarray([[x0, y0], [x1, y0], [x1, y1], [x0, y1], [x0, y0]]))
    axis.plot(outline[:, 0], outline[:, 1], **style)


def draw_panels(
    image: np.ndarray,
    world_to_pixel,
    panels: Sequence[Panel],
    grid: Grid = metric.DEFAULT_GRID,
    *,
    scene_boxes: np.ndarray | None = None,
    max_points: int = 300,
    suptitle: str | None = None,
    legend_extra: Sequence[Any] = (),
):
    """A matplotlib Figure with one panel per `Panel`: image, density (with its colour bar), samples, mode,
    references, and a legend below (`legend_extra`: more handles, for what a caller draws on top).

    `scene_boxes (B, 2, 2)`, if given, are outlined faintly (the obstacles).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    mapping = _as_mapping(world_to_pixel)
    xs, ys = np.meshgrid(grid.edges(0), grid.edges(1), indexing="ij")
    corners = _to_pixels(mapping, np.stack([xs, ys], axis=-1)).reshape(xs.shape + (2,))
    height, width = image.shape[:2]
    figure, axes = plt.subplots(1, len(panels), figsize=(4.2 * len(panels), 4.2 * height / width + 0.6), squeeze=False)
    for axis, panel in zip(axes[0], panels):
        axis.imshow(image, extent=(-0.5, width - 0.5, height - 0.5, -0.5))
        density = np.ma.masked_less_equal(np.asarray(panel.heatmap, dtype=float), 0.0)
        mesh = axis.pcolormesh(corners[..., 0], corners[..., 1], density, cmap="inferno", alpha=0.55, shading="flat")
        if density.count():
            figure.colorbar(mesh, ax=axis, fraction=0.035, pad=0.02).set_label("placement density", fontsize=7)
        for box in np.asarray(scene_boxes if scene_boxes is not None else [], dtype=float).reshape(-1, 2, 2):
            _outline(axis, mapping, box, color="white", linewidth=0.8, alpha=0.7)
        for box in np.asarray(panel.references, dtype=float).reshape(-1, 2, 2):
            _outline(axis, mapping, box, color="cyan", linewidth=1.5)
        samples = np.asarray(panel.samples, dtype=float)[:max_points]
        if len(samples) and np.all(np.isfinite(samples)):
            pixels = _to_pixels(mapping, samples)
            axis.scatter(pixels[:, 0], pixels[:, 1], s=3, color="white", edgecolors="none", alpha=0.8)
        if np.all(np.isfinite(panel.mode)):
            mode = _to_pixels(mapping, panel.mode)
            axis.scatter(mode[:, 0], mode[:, 1], s=120, marker="*", color="lime", edgecolors="black")
        lines = [wrapped for line in panel.title.splitlines() for wrapped in textwrap.wrap(line, 48)]
        axis.set_title("\n".join(lines), fontsize=9)
        axis.set_xlim(-0.5, width - 0.5)
        axis.set_ylim(height - 0.5, -0.5)
        axis.set_axis_off()
    if suptitle:
        figure.suptitle(suptitle, fontsize=10)
    handles = [*_legend_handles(), *legend_extra]
    columns = 2 if len(panels) == 1 else 4
    rows = -(-len(handles) // columns)
    figure.legend(handles=handles, loc="lower center", ncols=columns, fontsize=7, facecolor="0.3", labelcolor="white")
    figure.tight_layout(rect=(0, 0.02 + 0.055 * rows, 1, 1))
    return figure


def _legend_handles() -> list:
    from matplotlib.lines import Line2D

    return [
        Line2D([], [], color="cyan", lw=1.5, label="reference objects"),
        Line2D([], [], color="white", lw=0.8, markeredgecolor="gray", label="other objects (obstacles)"),
        Line2D([], [], ls="", marker="o", ms=3, color="white", markeredgecolor="gray", label="sampled placements"),
        Line2D([], [], ls="", marker="*", ms=10, color="lime", markeredgecolor="black", label="mode (the placement)"),
    ]


def choose_fig5_tuples(
    rng: np.random.Generator,
    boxes: np.ndarray,
    half_extents,
    names: Sequence[str] | None = None,
    grid: Grid = metric.DEFAULT_GRID,
    max_candidates: int = 120,
    scene: str = "scene",
) -> list[tuple[str, list[GroundedTuple], np.ndarray]]:
    """Three `(title, tuples, reference boxes)`, one per panel kind: the candidate of each kind
    with the largest feasible region, among candidates in an order drawn from `rng` (at most
    `max_candidates` per kind). `names` label the objects in titles. Raises NoFeasiblePlacement
    naming `scene` when a kind has no feasible candidate.
    """
    boxes = np.asarray(boxes, dtype=float).reshape(-1, 2, 2)
    names = list(names) if names is not None else [f"object {i}" for i in range(len(boxes))]

    def area(tuples):
        return int(metric.feasible_grid(metric.encode_problem(tuples, boxes, half_extents), grid).sum())

    table = [[GroundedTuple(name)] for name in rng.permutation(relations.RELATION_NAMES)]
    pairs = [
        (int(i), str(r)) for i in rng.permutation(len(boxes)) for r in rng.permutation(relations.OBJECT_RELATION_NAMES)
    ]
    single = [[GroundedTuple(r, boxes[i])] for i, r in pairs]
    double = [
        [GroundedTuple(r1, boxes[i]), GroundedTuple(r2, boxes[j])]
        for (i, r1), (j, r2) in itertools.product(pairs, repeat=2)
        if i < j
    ]
    double = [double[k] for k in rng.permutation(len(double))]
    chosen = []
    for kind, candidates in zip(PANEL_KINDS, (table, single, double)):
        areas = [area(t) for t in candidates[:max_candidates]]
        if not areas or max(areas) == 0:
            raise NoFeasiblePlacement(scene, f"no {kind} among {len(areas)} candidates has a feasible placement")
        tuples = candidates[int(np.argmax(areas))]
        parts, references = [], []
        for grounded in tuples:
            if grounded.reference_box is None:
                parts.append(f"{grounded.relation} part of the table")
            else:
                index = next(i for i, box in enumerate(boxes) if np.array_equal(box, grounded.reference_box))
                parts.append(f"{grounded.relation} of the {names[index]}")
                references.append(grounded.reference_box)
        chosen.append((f"{kind}: " + " and ".join(parts), tuples, np.asarray(references).reshape(-1, 2, 2)))
    return chosen


def fig5(
    key,
    image: np.ndarray,
    world_to_pixel,
    boxes: np.ndarray,
    half_extents,
    *,
    rng: np.random.Generator,
    names: Sequence[str] | None = None,
    config: Any = None,
    suptitle: str | None = None,
    scene: str = "scene",
):
    """Fig. 5 for one scene: chooses the three panels' tuples, samples them and draws them."""
    import jax

    from ocplace.models.placement.sampler import SamplerConfig, sample_placements

    config = config or SamplerConfig()
    chosen = choose_fig5_tuples(rng, boxes, half_extents, names, config.grid, scene=scene)
    problems = metric.stack_problems([metric.encode_problem(t, boxes, half_extents) for _, t, _ in chosen])
    result = jax.device_get(sample_placements(key, problems, config))
    panels = [
        Panel(title, result.heatmap[i], result.samples[i], result.mode[i], references)
        for i, (title, _, references) in enumerate(chosen)
    ]
    return draw_panels(image, world_to_pixel, panels, config.grid, scene_boxes=boxes, suptitle=suptitle)


def save_figure(figure, path: str | Path, style: FigureStyle = FigureStyle()) -> Path:
    """Writes `figure` atomically in `style`'s format (`path` with that suffix), closes it and returns the path."""
    import matplotlib.pyplot as plt

    from ocplace.paths import atomic_path

    path = Path(path).with_suffix(f".{style.format}")
    with atomic_path(path) as tmp:
        figure.savefig(tmp, format=style.format, dpi=style.dpi)
    plt.close(figure)
    return path
