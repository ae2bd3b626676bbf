"""The sample-efficiency figure (paper Fig. 7): overall success against the share of training data."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ocplace.eval.statistics import base_runs, repeats
from ocplace.eval.table import unseen_mean

if TYPE_CHECKING:
    from ocplace.models.placement.figures import FigureStyle

# One point of a curve: (fraction, mean %, standard deviation % over the runs with other seeds, runs).
Point = tuple[float, float, float, int]


def efficiency_curves(results: Mapping[str, Any]) -> dict[str, dict[str, list[Point]]]:
    """Per method label: `seen` and `unseen` (1:1 mean of unseen_obj and unseen_inst) as points over the fractions,
    each the mean and spread of the row's runs at that fraction (its seeds and backbone seeds, `repeats`)."""
    curves: dict[str, dict[str, list[Point]]] = {}
    for entry in sorted(base_runs(results), key=lambda e: e["fraction"]):
        runs = repeats(results, entry)
        seen = [overall for run in runs if (overall := _seen(run)) is not None]
        unseen = [value for run in runs if (value := unseen_mean(run)) is not None]
        lines = curves.setdefault(entry["label"], {"seen": [], "unseen": []})
        for panel, values in (("seen", seen), ("unseen", unseen)):
            if values:
                percent = 100 * np.asarray(values, float)
                lines[panel].append((entry["fraction"], float(percent.mean()), float(percent.std()), len(values)))
    return {label: lines for label, lines in curves.items() if len(lines["seen"]) > 1 or len(lines["unseen"]) > 1}


def _seen(entry: Mapping[str, Any]) -> float | None:
    success = entry["subsets"].get("seen", {}).get("aggregate", {}).get("overall", {}).get("success")
    return None if success is None else float(success)


def plot_sample_efficiency(results: Mapping[str, Any], path: str | Path, style: FigureStyle | None = None) -> Path:
    """Two panels (seen, unseen), one line per method with more than one fraction, each point the mean over the
    row's runs with a bar of one standard deviation where it has several; written at `path` in `style`."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ocplace.models.placement.figures import FigureStyle, save_figure

    curves = efficiency_curves(results)
    runs = max((point[3] for lines in curves.values() for line in lines.values() for point in line), default=1)
    figure, axes = plt.subplots(1, 2, figsize=(9, 3.6), sharey=True)
    for axis, panel, title in zip(axes, ("seen", "unseen"), ("Seen", "Unseen (mean of obj and inst)")):
        for label, lines in curves.items():
            if lines[panel]:
                fractions, means, spreads, _ = zip(*lines[panel])
                axis.errorbar([100 * f for f in fractions], means, yerr=spreads, marker="o", capsize=3, label=label)
        axis.set_title(title)
        axis.set_xlabel("training data (%)")
        axis.set_xticks([25, 50, 75, 100])
        axis.grid(alpha=0.3)
    axes[0].set_ylabel("overall success (%)" + (f", mean ± sd over up to {runs} runs" if runs > 1 else ""))
    axes[0].legend(fontsize=8)
    figure.tight_layout()
    return save_figure(figure, path, style or FigureStyle())
