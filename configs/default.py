"""The paper's protocol: 2000 + 4 x 400 scenes, every method, the sample-efficiency study."""

from pathlib import Path

from ocplace.experiments.experiment import DatasetSizes, EvalPlan, Experiment, TaskCpus
from ocplace.methods.registry import recipe_presets
from ocplace.models import offline_recipes
from ocplace.vocabulary import TEST_SUBSETS


def get_config() -> Experiment:
    return Experiment(
        name="default",
        out=Path("out/reproduce"),
        seed=0,
        dataset=DatasetSizes(train_scenes=2000, test_scenes=400, physical_scenes=100, seed=0),
        backbone=offline_recipes.default_config(),  # what `load_backbone("offline")` loads
        recipes=recipe_presets("default"),  # each learning row's PRESETS["default"], in methods/<row>/recipe.py
        evaluation=EvalPlan(
            methods=None,
            fractions=(0.25, 0.5, 0.75, 1.0),
            fraction_methods=("ours", "grids", "no_pretrain", "no_llm"),
            num_samples=1024,
            parser="offline",
            subsets=TEST_SUBSETS,
            seeds=1,
        ),
        cpus=TaskCpus(pretrain=2, train=2),
    )
