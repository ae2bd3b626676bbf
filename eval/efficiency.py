"""The sample-efficiency figure (paper Fig. 7): overall success against the share of training data."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from ocplace.eval.statistics import base_runs
from ocplace.eval.table import unseen_mean


def efficiency_curves(results: Mapping[str, Any]) -> dict[str, dict[str, list[tuple[float, float]]]]:
    """Per method label: `seen` and `unseen` (1:1 mean of unseen_obj and unseen_inst) as (fraction, %) points."""
    curves: dict[str, dict[str, list[tuple[float, float]]]] = {}
    for entry in sorted(base_runs(results), key=lambda e: e["fraction"]):
        seen = entry["subsets"].get("seen", {}).get("aggregate", {}).get("overall", {}).get("success")
        unseen = unseen_mean(entry)
        lines = curves.setdefault(entry["label"], {"seen": [], "unseen": []})
        if seen is not None:
            lines["seen"].append((entry["fraction"], 100 * seen))
        if unseen is not None:
            lines["unseen"].append((entry["fraction"], 100 * unseen))
    return {label: lines for label, lines in curves.items() if len(lines["seen"]) > 1 or len(lines["unseen"]) > 1}


def plot_sample_efficiency(results: Mapping[str, Any], path: str | Path) -> Path:
    """Two panels (seen, unseen), one line per method with more than one fraction; a PNG at `path`."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ocplace.paths import atomic_path

    curves = efficiency_curves(results)
    figure, axes = plt.subplots(1, 2, figsize=(9, 3.6), sharey=True)
    for axis, panel, title in zip(axes, ("seen", "unseen"), ("Seen", "Unseen (mean of obj and inst)")):
        for label, lines in curves.items():
            if lines[panel]:
                fractions, success = zip(*lines[panel])
                axis.plot([100 * f for f in fractions], success, marker="o", label=label)
        axis.set_title(title)
        axis.set_xlabel("training data (%)")
        axis.set_xticks([25, 50, 75, 100])
        axis.grid(alpha=0.3)
    axes[0].set_ylabel("overall success (%)")
    axes[0].legend(fontsize=8)
    figure.tight_layout()
    path = Path(path)
    with atomic_path(path) as tmp:
        figure.savefig(tmp, format="png", dpi=120)
    plt.close(figure)
    return path
