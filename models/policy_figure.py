"""One figure of what the policy did in a scene: image, boxes, grounded references with their
probabilities, the placement density, samples and the mode (built on `placement.figures`)."""

from __future__ import annotations

import textwrap
from typing import TYPE_CHECKING

import numpy as np

from ocplace.models.placement.figures import Panel, draw_panels

if TYPE_CHECKING:
    from ocplace.models.policy import Placement

REFERENCE_COLOURS = ("cyan", "magenta", "yellow", "orange")


def placement_figure(placement, rgb: np.ndarray, camera, max_points: int = 300):
    """A matplotlib Figure for a `models.policy.Placement` (placed or not) over its `rgb` image."""
    nx, ny = placement.grid.shape
    heatmap = placement.heatmap if placement.heatmap is not None else np.zeros((nx, ny), np.float32)
    samples = placement.samples if placement.samples is not None else np.zeros((0, 2))
    mode = placement.mode if placement.mode is not None else np.full(2, np.nan)
    references = [ref.aabb for ref in placement.references if ref.aabb is not None]
    parse = "; ".join(f"<{ref}, {rel}>" for ref, rel in placement.pairs) or "no parse"
    status = (
        f"NOT PLACED: {short_reason(placement.failure)}"  # the whole message is printed beside the figure
        if placement.error is not None
        else f"mode ({mode[0]:+.3f}, {mode[1]:+.3f}) m"
    )
    title = f"{parse}\n{status}"
    panel = Panel(title, heatmap, samples, mode, np.asarray(references).reshape(-1, 2, 2))
    figure = draw_panels(
        rgb,
        camera.world_to_pixel,
        [panel],
        placement.grid,
        scene_boxes=placement.aabbs,
        max_points=max_points,
        suptitle="\n".join(textwrap.wrap(placement.instruction, 56)),
        legend_extra=_box_legend(),
    )
    axis = figure.axes[0]
    for index, (u0, v0, u1, v1) in enumerate(np.asarray(placement.boxes).reshape(-1, 4)):
        _rectangle(axis, (u0, v0, u1, v1), "white", 0.8, "--")
        axis.text(u0, v0 - 2, f"#{index}", color="white", fontsize=6, va="bottom")
    for k, ref in enumerate(placement.references):
        colour = REFERENCE_COLOURS[k % len(REFERENCE_COLOURS)]
        label = f"{ref.phrase!r} p={ref.probability:.2f} ({ref.relation})"
        if ref.is_table:
            axis.text(
                4,
                14 + 14 * k,
                f"table: {label}",
                color=colour,
                fontsize=7,
                bbox={"facecolor": "black", "alpha": 0.5, "pad": 1},
            )
            continue
        u0, v0, u1, v1 = ref.box
        _rectangle(axis, (u0, v0, u1, v1), colour, 1.8, "-")
        axis.text(
            u0,
            v1 + 2 + 12 * k,
            label,
            color=colour,
            fontsize=7,
            va="top",
            bbox={"facecolor": "black", "alpha": 0.5, "pad": 1},
        )
    return figure


def short_reason(failure: str | None, limit: int = 60) -> str:
    """The failure's kind and the start of its message, for a title (`NoFeasiblePlacement: no cell of the grid...`)."""
    text = " ".join((failure or "unknown").split())
    return text if len(text) <= limit else text[: limit - 3].rstrip() + "..."


def _box_legend() -> list:
    """The legend of the boxes this module draws over `draw_panels`' figure."""
    from matplotlib.lines import Line2D

    return [
        Line2D([], [], color="white", lw=0.8, ls="--", label="object boxes: the visual tokens (#index)"),
        Line2D([], [], color=REFERENCE_COLOURS[0], lw=1.8, label="grounded reference (p: its probability)"),
    ]


def _rectangle(axis, box, colour: str, width: float, style: str) -> None:
    from matplotlib.patches import Rectangle

    u0, v0, u1, v1 = (float(x) - 0.5 for x in box)  # pixel edges: pixel centres sit at integers
    axis.add_patch(
        Rectangle((u0, v0), u1 - u0, v1 - v0, fill=False, edgecolor=colour, linewidth=width, linestyle=style)
    )


def save_placement(policy, scene, key, path) -> Placement:
    """Places the held object in `scene` (a `models.policy.SceneInput`) and saves the figure to `path`."""
    [placement] = policy.place_many([scene], key)
    save_placement_figure(placement, scene, path)
    return placement


def save_placement_figure(placement, scene, path, style=None) -> None:
    """Draws what the policy did in `scene` (a `models.policy.SceneInput`) into `path` (`style`: a `FigureStyle`,
    by default a PNG)."""
    from ocplace.models.placement.figures import FigureStyle, save_figure
    from ocplace.sim.pinhole import PinholeCamera

    figure = placement_figure(placement, scene.rgb, PinholeCamera.from_any(scene.camera))
    save_figure(figure, path, style or FigureStyle())
