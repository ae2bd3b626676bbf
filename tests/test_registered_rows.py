"""Every registered row of Table I goes through its `MethodSpec` the way `reproduce` takes it: trained at smoke size
(when it learns), loaded, and run on test scenes, as mujoco_playground's `manipulation_test.py` runs every registered
environment. The tiny backbone knows nothing, so a row that grounds may ground wrong and then refuse a scene it
cannot place; what it may not do is fail any other way, place off the table, return NaN, or place nothing."""

import json

import jax
import numpy as np
import pytest

from ocplace.eval.api import MethodOutput
from ocplace.eval.harness import redacted
from ocplace.methods.api import LoadContext
from ocplace.methods.registry import method_specs, registered_names
from ocplace.paths import WEIGHTS_FILE
from ocplace.sim.dataset.job import scene_dirs
from ocplace.sim.dataset.records import read_scene
from ocplace.sim.workspace import DEFAULT_TABLE
from ocplace.vocabulary import TEST_SUBSETS

SAMPLES = 16
REFUSALS = ("NoFeasiblePlacement: ", "InvalidPlacementProblem: ")  # of a wrong grounding


@pytest.fixture(scope="module")
def scenes(smoke_dataset):
    """The test scenes placed against the table alone (the easiest to ground), four of them."""
    records = [read_scene(folder) for subset in TEST_SUBSETS for folder in scene_dirs(smoke_dataset, subset)]
    return [redacted(record) for record in records if record.level == "table"][:4]


@pytest.mark.parametrize("name", registered_names())
def test_every_row_trains_loads_and_places(name, smoke_rows, scenes, tiny_backbone_spec):
    spec = method_specs()[name]
    run_dir = None if spec.train is None else smoke_rows[name]
    assert run_dir is None or (run_dir / WEIGHTS_FILE).is_file()
    method = spec.load(LoadContext(run_dir, tiny_backbone_spec, num_samples=SAMPLES))
    assert len(scenes) == 4
    outputs = method.run(scenes, jax.random.key(0))
    assert len(outputs) == len(scenes) and all(isinstance(output, MethodOutput) for output in outputs)
    placed = [output for output in outputs if output.failure is None]
    assert placed, [output.failure for output in outputs]
    for output in outputs:  # a refusal comes after grounding, and says which placement could not be made
        if output.failure is not None:
            assert output.grounded is not None and output.failure.startswith(REFUSALS), output.failure
    low, high = np.asarray(DEFAULT_TABLE.bounds[0]), np.asarray(DEFAULT_TABLE.bounds[1])
    for output in placed:
        mode = np.asarray(output.mode)
        assert mode.shape == (2,) and np.all(np.isfinite(mode)) and np.all((low <= mode) & (mode <= high))
        if output.samples is not None:
            samples = np.asarray(output.samples)
            assert samples.shape == (SAMPLES, 2) and np.all(np.isfinite(samples))
    described = json.loads(json.dumps(method.describe()))
    assert described
