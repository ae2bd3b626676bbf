"""Tests and CI: the smoke dataset (12 + 4 x 8 scenes), seconds-long recipes, every method."""

import dataclasses
from pathlib import Path

from ocplace.experiments.experiment import DatasetSizes, EvalPlan, Experiment, TaskCpus
from ocplace.methods.cliport import recipe as cliport
from ocplace.methods.grids import recipe as grids
from ocplace.methods.no_llm.recipe import NoLlmRecipe
from ocplace.methods.no_pretrain import recipe as no_pretrain
from ocplace.methods.ours import recipe as ours
from ocplace.models import offline_recipes
from ocplace.train.schedule import Schedule
from ocplace.vocabulary import TEST_SUBSETS


def get_config() -> Experiment:
    return Experiment(
        name="smoke",
        out=Path("out/smoke"),
        seed=0,
        dataset=DatasetSizes(train_scenes=12, test_scenes=8, physical_scenes=2, seed=0),
        backbone=offline_recipes.smoke_config(),  # a tiny tower, four objects, two scenes, a few steps
        recipes={
            "ours": ours.chosen_adapters(ours.smoke_config()),
            "ours_paper": ours.smoke_config(),
            "no_llm": NoLlmRecipe(
                schedule=Schedule(
                    steps=120, batch_size=8, learning_rate=3e-3, warmup_steps=10, chunk_steps=40, checkpoint_every=40
                ),
                hidden=32,
            ),
            "no_pretrain": no_pretrain.NoPretrainRecipe(
                no_pretrain.smoke_config(),
                dataclasses.replace(no_pretrain.SCHEDULE, steps=150, batch_size=4, warmup_steps=3, checkpoint_every=50),
                log_every=10,
            ),
            "grids": grids.GridsRecipe(
                grids.smoke_grid_config(),
                Schedule(
                    steps=120, batch_size=4, learning_rate=1e-2, warmup_steps=5, chunk_steps=40, checkpoint_every=40
                ),
            ),
            "cliport": cliport.CliportRecipe(
                cliport.smoke_config(),
                Schedule(
                    steps=60, batch_size=4, learning_rate=3e-3, warmup_steps=5, chunk_steps=20, checkpoint_every=20
                ),
                num_targets=4,
            ),
        },
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
