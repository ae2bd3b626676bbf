"""The paper's protocol: 2000 + 4 x 400 scenes, every method, the sample-efficiency study."""

from pathlib import Path

from ocplace.experiments.experiment import DatasetSizes, EvalPlan, Experiment, MethodRecipes, TaskCpus
from ocplace.models import no_pretrain_config, offline_recipes
from ocplace.models.baselines.cliport_config import CliportConfig
from ocplace.models.baselines.grid_config import GridConfig
from ocplace.train import config as ours
from ocplace.train.recipes import (
    CliportRecipe,
    GridsRecipe,
    NoLlmTrainConfig,
    NoPretrainRecipe,
    NoPretrainTrainConfig,
    Schedule,
)
from ocplace.vocabulary import TEST_SUBSETS


def get_config() -> Experiment:
    return Experiment(
        name="default",
        out=Path("out/reproduce"),
        seed=0,
        dataset=DatasetSizes(train_scenes=2000, test_scenes=400, physical_scenes=100, seed=0),
        backbone=offline_recipes.default_config(),  # what `load_backbone("offline")` loads
        recipes=MethodRecipes(
            # The paper's budget (200K steps at batch 1) with rule A's adapters; beside it the paper's adapters.
            ours=ours.default_config(),
            ours_paper=ours.paper_config(),
            no_llm=NoLlmTrainConfig(),
            no_pretrain=NoPretrainRecipe(no_pretrain_config.default_config(), NoPretrainTrainConfig()),
            # The paper's budget for the adapters: 200K steps at batch 1, warm-up then cosine decay.
            grids=GridsRecipe(
                GridConfig(),
                Schedule(
                    steps=200_000,
                    batch_size=1,
                    learning_rate=1e-4,
                    warmup_steps=1_000,
                    chunk_steps=2_000,
                    checkpoint_every=50_000,
                ),
            ),
            # 0.6-1.3 s per step of 8 on 2 CPU cores: 10-20 min, 4 epochs of 2000 scenes (docs/baselines.md).
            cliport=CliportRecipe(
                CliportConfig(),
                Schedule(
                    steps=1_000, batch_size=8, learning_rate=1e-3, warmup_steps=50, chunk_steps=50, checkpoint_every=250
                ),
            ),
        ),
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
