"""Every registered row of Table I goes through its `MethodSpec` the way `reproduce` takes it: trained at smoke size
(when it learns), loaded, and run on test scenes, as mujoco_playground's `manipulation_test.py` runs every registered
environment. The tiny backbone knows nothing, so a row that grounds may ground wrong and then refuse a scene it
cannot place; what it may not do is fail any other way, place off the table, return NaN, or place nothing."""

import json
import os
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest

from ocplace.eval.api import MethodOutput
from ocplace.eval.harness import redacted
from ocplace.methods.contract import LoadContext
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
    run_dir = smoke_rows[spec.trained_as] if spec.needs_run else None
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


TOY_ROW = {
    "__init__.py": '"""A toy row: it places every object at the training split\'s mean oracle placement."""\n\n'
    "from toy_row.recipe import ToyRecipe\n\nTABLE_ROW = 99\nRECIPE = ToyRecipe\n",
    "recipe.py": """
import dataclasses


@dataclasses.dataclass(frozen=True)
class ToyRecipe:
    shift: float = 0.0  # added to the mean placement

    def validate(self):
        pass
""",
    "method.py": """
import dataclasses
import json

import numpy as np

from ocplace.eval.api import MethodOutput
from ocplace.methods.contract import MethodSpec
from ocplace.sim.dataset.job import scene_dirs
from ocplace.sim.dataset.records import SceneInfo, read_meta


def train(ctx):
    placements = [SceneInfo(read_meta(folder)).oracle.placement for folder in scene_dirs(ctx.dataset_dir, "train")]
    ctx.out_dir.mkdir(parents=True, exist_ok=True)
    mean = np.mean(placements, axis=0) + ctx.recipe.shift
    recipe = {"type": type(ctx.recipe).__name__, **dataclasses.asdict(ctx.recipe)}
    (ctx.out_dir / "mean.json").write_text(json.dumps({"mean": mean.tolist(), "recipe": recipe}))
    return ctx.out_dir


@dataclasses.dataclass
class MeanPlacement:
    mean: list
    name: str = "toy_row"

    def describe(self):
        return {"mean": self.mean}

    def run(self, scenes, key):
        return [MethodOutput(mode=np.asarray(self.mean), samples=None) for _ in scenes]


def load(ctx):
    return MeanPlacement(json.loads((ctx.trained_run / "mean.json").read_text())["mean"])


SPEC = MethodSpec("toy_row", "Toy mean placement", load=load, train=train, uses_backbone=False)
""",
}


def test_a_new_row_is_one_folder_that_reproduce_trains_and_scores(smoke_dataset, tiny_backbone_spec, tmp_path):
    """A row from outside the tree: its folder and one entry point, found by the registry in the `reproduce`
    process and in the workers it starts, trained with its `RECIPE`'s defaults, evaluated, and last in Table I by
    its `TABLE_ROW`."""
    from ocplace.eval import results
    from ocplace.methods.registry import ENTRY_POINTS

    site = tmp_path / "site"
    (site / "toy_row").mkdir(parents=True)
    for name, text in TOY_ROW.items():
        (site / "toy_row" / name).write_text(text)
    (site / "toy_row-0.1.dist-info").mkdir()
    (site / "toy_row-0.1.dist-info" / "METADATA").write_text("Metadata-Version: 2.1\nName: toy-row\nVersion: 0.1\n")
    (site / "toy_row-0.1.dist-info" / "entry_points.txt").write_text(f"[{ENTRY_POINTS}]\ntoy_row = toy_row\n")
    env = {**os.environ, "PYTHONPATH": str(site)}
    listed = subprocess.run(
        [sys.executable, "-c", "from ocplace.methods.registry import registered_names as r; print(*r())"],
        env=env,
        capture_output=True,
        text=True,
        check=True,
    )
    assert listed.stdout.split() == [*registered_names(), "toy_row"]
    out = tmp_path / "out"
    command = ["reproduce", "--experiment", "smoke", "--methods", "toy_row", "--dataset", str(smoke_dataset)]
    command += ["--backbone", tiny_backbone_spec, "--out", str(out), "--no-progress"]
    command += ["--set", "dataset.physical_scenes=0"]
    done = subprocess.run([sys.executable, "-m", "ocplace.cli", *command], env=env, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]
    saved = results.read_results(out / "results.json")
    (entry,) = saved["evaluations"]
    assert entry["key"] == "toy_row"
    # No experiment of ours names the row: its training got its own recipe's defaults.
    assert json.loads(Path(entry["run_dir"], "mean.json").read_text())["recipe"] == {"type": "ToyRecipe", "shift": 0.0}
    assert all(entry["subsets"][subset]["aggregate"]["overall"]["scenes"] == 8 for subset in TEST_SUBSETS)
    assert "| Toy mean placement |" in done.stdout


@pytest.mark.parametrize(
    "entry, package, message",
    [
        ("ghost_row", "no_such_row_package", "its package no_such_row_package does not import"),
        ("ours", "toy_row", "toy_row registers 'ours', a row ocplace.methods.ours has"),
        ("toy_row", "toy_row", "toy_row must set TABLE_ROW"),
    ],
)
def test_a_bad_entry_point_is_a_typed_error_naming_it(entry, package, message, tmp_path, monkeypatch):
    """A row another distribution names that is not installed, takes a name ours has, or has no place in Table I."""
    from ocplace.errors import EvaluationError
    from ocplace.methods.registry import ENTRY_POINTS

    (tmp_path / "toy_row").mkdir()
    (tmp_path / "toy_row" / "__init__.py").write_text('"""A toy row without its place in Table I."""\n')
    (tmp_path / "toy_row-0.1.dist-info").mkdir()
    (tmp_path / "toy_row-0.1.dist-info" / "METADATA").write_text("Metadata-Version: 2.1\nName: toy-row\nVersion: 0.1\n")
    (tmp_path / "toy_row-0.1.dist-info" / "entry_points.txt").write_text(f"[{ENTRY_POINTS}]\n{entry} = {package}\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(EvaluationError, match=message):
        registered_names()


def test_a_row_from_outside_names_a_dataclass_recipe(tmp_path, monkeypatch):
    """Experiments are saved as JSON and read back by each row's `RECIPE`: a row naming something else is refused."""
    from ocplace.errors import EvaluationError
    from ocplace.methods.registry import ENTRY_POINTS, in_tree, recipe_types

    (tmp_path / "loose_row").mkdir()
    (tmp_path / "loose_row" / "__init__.py").write_text(
        '"""A row whose recipe is no type."""\n\nTABLE_ROW = 98\nRECIPE = 3\n'
    )
    (tmp_path / "loose_row-0.1.dist-info").mkdir()
    (tmp_path / "loose_row-0.1.dist-info" / "METADATA").write_text(
        "Metadata-Version: 2.1\nName: loose-row\nVersion: 0.1\n"
    )
    (tmp_path / "loose_row-0.1.dist-info" / "entry_points.txt").write_text(f"[{ENTRY_POINTS}]\nloose_row = loose_row\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    assert in_tree("ours") and not in_tree("loose_row")
    with pytest.raises(EvaluationError, match="row 'loose_row': RECIPE must be a dataclass type"):
        recipe_types()
