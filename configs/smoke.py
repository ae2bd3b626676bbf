"""Tests and CI: the smoke dataset (12 + 4 x 8 scenes), seconds-long recipes, every method."""

from pathlib import Path

from ocplace.experiments.experiment import DatasetSizes, EvalPlan, Experiment, TaskCpus
from ocplace.methods.registry import recipe_presets
from ocplace.models import offline_recipes
from ocplace.vocabulary import TEST_SUBSETS


def get_config() -> Experiment:
    return Experiment(
        name="smoke",
        out=Path("out/smoke"),
        seed=0,
        dataset=DatasetSizes(train_scenes=12, test_scenes=8, physical_scenes=2, seed=0),
        backbone=offline_recipes.smoke_config(),  # a tiny tower, four objects, two scenes, a few steps
        recipes=recipe_presets("smoke"),  # each learning row's PRESETS["smoke"], in methods/<row>/recipe.py
        evaluation=EvalPlan(
            methods=None,
            fractions=(1.0,),
            fraction_methods=("ours", "grids", "no_pretrain", "no_llm"),
            num_samples=64,
            parser="offline",
            subsets=TEST_SUBSETS,
            seeds=1,
        ),
        cpus=TaskCpus(pretrain=2, train=1),  # tiny trainings: side by side, each one CPU wide
    )
