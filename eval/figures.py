"""The paper's figures from a results JSON and its dataset: Fig. 5 (placement densities), Fig. 6
(cases: where each method put the held object) and Fig. 7 (sample efficiency).

Fig. 6 needs no model: the results store every scene's mode per method, so it draws those over
the scene with the ground-truth references and the oracle's feasible region.
"""

from __future__ import annotations

import textwrap
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ocplace.errors import EvaluationError
from ocplace.eval.statistics import full_runs

if TYPE_CHECKING:
    from ocplace.models.placement.figures import FigureStyle
    from ocplace.sim.dataset.job import ListedScene
    from ocplace.sim.dataset.records import SceneRecord

FIG5, FIG6, FIG7 = "fig5_placement_distributions.png", "fig6_cases.png", "fig7_sample_efficiency.png"
CASE_METHODS = ("ours", "cliport")
CASE_LEVELS = ("1obj", "2obj")
METHOD_COLOURS = ("deepskyblue", "orange", "magenta", "lime", "red", "yellow")


def _full_runs_by_method(results: Mapping[str, Any]) -> dict[str, dict[str, Any]]:
    return {entry["method"]: entry for entry in full_runs(results)}


def _outcomes_by_scene(entry: Mapping[str, Any], subset: str) -> dict[str, dict[str, Any]]:
    return {scene["id"]: scene for scene in entry["subsets"].get(subset, {}).get("scenes", [])}


def choose_cases(
    results: Mapping[str, Any], methods: Sequence[str] = CASE_METHODS, levels: Sequence[str] = CASE_LEVELS
) -> list[tuple[str, str]]:
    """`(subset, scene id)` per evaluated subset and level: the first scene where the methods'
    successes differ, else the first scene of that level. Full-data runs only."""
    entries = _full_runs_by_method(results)
    missing = [m for m in methods if m not in entries]
    if missing:
        raise EvaluationError(
            f"the results hold no full-data evaluation of {missing}; evaluate them first "
            f"(evaluated: {', '.join(entries) or 'none'})"
        )
    cases = []
    for subset in results["settings"]["subsets"]:
        outcomes = [_outcomes_by_scene(entries[m], subset) for m in methods]
        ids = [scene_id for scene_id in outcomes[0] if all(scene_id in o for o in outcomes[1:])]
        for level in levels:
            of_level = [i for i in ids if outcomes[0][i]["level"] == level]
            disagree = [i for i in of_level if len({o[i]["success"] for o in outcomes}) > 1]
            if of_level:
                cases.append((subset, (disagree or of_level)[0]))
    return cases


def _draw_case(axis: Any, record: SceneRecord, outcomes: Sequence[tuple[str, dict[str, Any]]]) -> None:
    from matplotlib.patches import Rectangle

    from ocplace.sim.dataset.show import feasible_overlay

    axis.imshow(feasible_overlay(record))
    references = {t.reference_object_id for t in record.tuples or ()}
    for object_id, (u0, v0, u1, v1) in zip(record.boxes.object_ids, record.boxes.boxes, strict=True):
        if object_id in references:
            axis.add_patch(
                Rectangle((u0 - 0.5, v0 - 0.5), u1 - u0, v1 - v0, fill=False, edgecolor="white", linewidth=1.5)
            )
    camera = record.camera
    for k, (label, outcome) in enumerate(outcomes):
        colour = METHOD_COLOURS[k % len(METHOD_COLOURS)]
        verdict = "success" if outcome["success"] else ("not placed" if outcome["failure"] else "failure")
        if outcome["mode"] is not None:
            u, v = camera.table_to_pixel(np.asarray(outcome["mode"]))
            axis.scatter(
                [u],
                [v],
                s=90,
                marker="o" if outcome["success"] else "X",
                color=colour,
                edgecolors="black",
                linewidths=0.8,
                zorder=3,
            )
        axis.text(
            6,
            18 + 20 * k,
            f"{label}: {verdict}",
            color=colour,
            fontsize=7,
            bbox={"facecolor": "black", "alpha": 0.6, "pad": 1},
        )
    axis.set_title(f"{record.id} ({record.level})\n" + "\n".join(textwrap.wrap(record.instruction, 48)), fontsize=7)
    axis.set_axis_off()


def _listed_scene(dataset_dir: Path, subset: str, scene_id: str) -> ListedScene:
    """The `ListedScene` the results name, found among those the manifest lists, never joined from the name."""
    from ocplace.sim.dataset.job import listed_scenes

    listed = {scene.name: scene for scene in listed_scenes(dataset_dir, subset)}
    if scene_id not in listed:
        raise EvaluationError(
            f"scene {scene_id!r} of the results is not in the manifest of {dataset_dir}: the "
            "results come from another dataset; pass the dataset they were made on"
        )
    return listed[scene_id]


def plot_cases(
    results: Mapping[str, Any],
    path: str | Path,
    dataset_dir: str | Path | None = None,
    methods: Sequence[str] = CASE_METHODS,
    cases: Sequence[tuple[str, str]] | None = None,
    style: FigureStyle | None = None,
) -> Path:
    """Fig. 6: one panel per case, each method's mode (o success, X failure) over the scene with its
    feasible region (green) and ground-truth references (white boxes), with a legend. Written at `path` in `style`
    (default: PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ocplace.models.placement.figures import FigureStyle, save_figure

    dataset_dir = Path(dataset_dir or results["dataset"]["dir"])
    cases = list(cases or choose_cases(results, methods))
    if not cases:
        raise EvaluationError("no scene to draw: the results hold no scene of the chosen levels")
    entries = _full_runs_by_method(results)
    columns = min(len(cases), 3)
    rows = -(-len(cases) // columns)
    figure, axes = plt.subplots(rows, columns, figsize=(4.4 * columns, 3.9 * rows), squeeze=False)
    for axis in axes.flat[len(cases) :]:
        axis.set_axis_off()
    for axis, (subset, scene_id) in zip(axes.flat, cases):
        record = _listed_scene(dataset_dir, subset, scene_id).read()
        outcomes = [(entries[m]["label"], _outcomes_by_scene(entries[m], subset)[scene_id]) for m in methods]
        _draw_case(axis, record, outcomes)
    labels = [entries[m]["label"] for m in methods]
    figure.legend(handles=_case_legend(labels), loc="lower center", ncols=3, fontsize=7)
    figure.tight_layout(rect=(0, 0.08, 1, 1))
    return save_figure(figure, path, style or FigureStyle())


def _case_legend(labels: Sequence[str]) -> list[Any]:
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    handles: list[Any] = [
        Line2D(
            [],
            [],
            ls="",
            marker="o",
            color=METHOD_COLOURS[k % len(METHOD_COLOURS)],
            markeredgecolor="black",
            label=f"{label}: placed, success",
        )
        for k, label in enumerate(labels)
    ]
    handles += [
        Line2D([], [], ls="", marker="X", color="gray", markeredgecolor="black", label="placed, failure"),
        Patch(facecolor="limegreen", alpha=0.5, label="where every tuple holds (feasible region)"),
        Patch(facecolor="none", edgecolor="black", label="reference objects (white boxes)"),
    ]
    return handles


def plot_fig5(
    dataset_dir: str | Path, path: str | Path, seed: int = 0, subset: str = "seen", style: FigureStyle | None = None
) -> Path:
    """Fig. 5 on the first scene of a test subset: a table region, one object relation, a composition."""
    import jax

    from ocplace.models.placement.figures import FigureStyle, fig5, save_figure
    from ocplace.sim.dataset.job import listed_scenes

    record = listed_scenes(Path(dataset_dir), subset)[0].read()
    boxes = np.array([obj.aabb for obj in record.objects], dtype=float)[:, :, :2]
    held = record.held_object
    figure = fig5(
        jax.random.key(seed),
        record.rgb,
        record.camera,
        boxes,
        held.footprint_half_extents,
        rng=np.random.default_rng(seed),
        names=[obj.human_name for obj in record.objects],
        suptitle=f"{record.id} | held: {held.human_name}",
        scene=record.id,
    )
    return save_figure(figure, path, style or FigureStyle())


def write_figures(
    results: Mapping[str, Any],
    out_dir: str | Path,
    dataset_dir: str | Path | None = None,
    seed: int = 0,
    style: FigureStyle | None = None,
) -> list[Path]:
    """Every paper figure the results allow: Fig. 5 always, Fig. 6 with Ours and CLIPort-Place
    evaluated (and per-scene outcomes, which a summary lacks), Fig. 7 with several training fractions; in `style`
    (default: PNG at 150 dpi)."""
    from ocplace.eval.efficiency import efficiency_curves, plot_sample_efficiency
    from ocplace.models.placement.figures import FigureStyle

    style = style or FigureStyle()
    style.validate()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    dataset_dir = Path(dataset_dir or results["dataset"]["dir"])
    if not dataset_dir.is_dir():
        raise EvaluationError(
            f"the dataset {dataset_dir} the results name is not there, nor at the same place relative to the results "
            "file (moved or deleted): pass --dataset DIR to `ocplace figures` (dataset_dir= in Python)"
        )
    written = [plot_fig5(dataset_dir, out_dir / FIG5, seed, style=style)]
    if set(CASE_METHODS) <= _full_runs_by_method(results).keys() and not results.get("summary"):
        written.append(plot_cases(results, out_dir / FIG6, dataset_dir, style=style))
    if efficiency_curves(results):
        written.append(plot_sample_efficiency(results, out_dir / FIG7, style))
    return written
