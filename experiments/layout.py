"""Where a `reproduce` output keeps each trained run: `OUT/runs/<row>/fraction-<f>[-seed-<s>][-backbone-<b>]`.

Apart from the pipeline, so that `ocplace evaluate --runs-from OUT` finds runs without importing it.
"""

from __future__ import annotations

from pathlib import Path


def run_directory(
    out: Path, name: str, fraction: float, seed: int | None = None, backbone_seed: int | None = None
) -> Path:
    """The folder of row `name`'s run on `fraction` of the training scenes (with a repeat's seeds, when one)."""
    folder = f"fraction-{fraction:.2f}" + ("" if seed is None else f"-seed-{seed}")
    folder += "" if backbone_seed is None else f"-backbone-{backbone_seed}"
    return out / "runs" / name / folder
