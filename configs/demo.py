"""`make demo`: 200 + 4 x 40 scenes, Ours, w/o Adapter and w/o LLM with a few minutes of training each, and Ours
with the joint decision (beyond the paper) on Ours' own run.

Its rows share one backbone and one set of features. The rows with an image tower of their own
(w/o CLIP pre-train, Raw Image Grids, CLIPort-Place) would double its time: `make reproduce` runs
them, or `--methods all` with the recipes below.
"""

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

# A tenth of the paper's steps at a higher peak rate: the demo dataset is small too.
DEMO_ADAPTERS = ours.OursRecipe(
    schedule=dataclasses.replace(
        ours.PAPER_SCHEDULE, steps=20_000, learning_rate=5e-4, warmup_steps=500, checkpoint_every=10_000
    ),
    eval_every=10_000,
)


def get_config() -> Experiment:
    return Experiment(
        name="demo",
        out=Path("out/demo"),
        seed=0,
        dataset=DatasetSizes(train_scenes=200, test_scenes=40, physical_scenes=10, seed=0),
        backbone=offline_recipes.demo_config(),  # the default architecture, 100 scenes, 75 steps
        recipes={
            "ours": ours.chosen_adapters(DEMO_ADAPTERS),
            "ours_paper": DEMO_ADAPTERS,  # not in the demo's rows; `--methods ours,ours_paper` trains it
            "no_llm": NoLlmRecipe(
                schedule=dataclasses.replace(
                    NoLlmRecipe().schedule, steps=3_000, warmup_steps=200, chunk_steps=500, checkpoint_every=1_500
                )
            ),
            "no_pretrain": no_pretrain.NoPretrainRecipe(
                no_pretrain.demo_config(),
                dataclasses.replace(no_pretrain.SCHEDULE, steps=75, warmup_steps=8, checkpoint_every=25),
                log_every=25,
            ),
            "grids": grids.GridsRecipe(
                grids.GridConfig(),
                Schedule(
                    steps=4_000,
                    batch_size=4,
                    learning_rate=1e-3,
                    warmup_steps=100,
                    chunk_steps=1_000,
                    checkpoint_every=2_000,
                ),
            ),
            "cliport": cliport.CliportRecipe(
                cliport.CliportConfig(),
                Schedule(
                    steps=100, batch_size=8, learning_rate=1e-3, warmup_steps=10, chunk_steps=50, checkpoint_every=50
                ),
            ),
        },
        evaluation=EvalPlan(
            methods=("ours", "ours_joint", "no_adapter", "no_llm"),  # the joint row places with Ours' run
            fractions=(1.0,),
            fraction_methods=("ours", "grids", "no_pretrain", "no_llm"),
            num_samples=1024,
            parser="offline",
            subsets=TEST_SUBSETS,
            seeds=1,
        ),
        cpus=TaskCpus(pretrain=2, train=2),  # JAX two wide: as fast alone as two one-wide side by side
    )
