"""A finished baseline run read back: its `run.json` and its weights file, verified.

`train/baseline_runs.py` writes the run (layout in its docstring); `grids.load_params` and
`cliport.load_params` build each network's parameters from what this returns, so evaluating a
baseline never needs `train`.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

from ocplace.errors import TrainingError
from ocplace.models import weights_file
from ocplace.paths import read_run_file, trained_weights


def load_run(run_dir: Path, method: str) -> tuple[dict, dict[str, np.ndarray], str]:
    """`(run_meta, flat arrays, sha256 of the weights file)` of a finished run of `method`, verified.

    `weights_file.unflatten_state` makes the tree of the arrays.
    """
    path = trained_weights(run_dir, "weights", "train the method first (`ocplace reproduce` trains missing runs)")
    run_meta = read_run_file(run_dir)
    arrays, metadata = weights_file.load_weights(
        path, f"delete {path.parent} and rerun `ocplace reproduce` (it trains missing runs)"
    )
    wanted, example = f"the weights of a {method} run", f"OUT/runs/{method}/fraction-1.00"
    weights_file.expect_kind(path, metadata, ["run"], wanted, example)
    if run_meta.get("method", method) != method:  # a run that names another row (older runs name none)
        kind = weights_file.weights_kind(metadata)
        raise TrainingError(f"{path} holds {kind}, not {wanted}; pass a run of the row you meant (e.g. `{example}`)")
    return run_meta, arrays, hashlib.sha256(path.read_bytes()).hexdigest()
