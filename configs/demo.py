"""`make demo`: 200 + 4 x 40 scenes, Ours, w/o Adapter and w/o LLM with a few minutes of training each, and Ours
with the joint decision (beyond the paper) on Ours' own run.

Its rows share one backbone and one set of features. The rows with an image tower of their own
(w/o CLIP pre-train, Raw Image Grids, CLIPort-Place) would double its time: `make reproduce` runs
them, or `--methods all` with the rows' demo presets (`PRESETS["demo"]` in methods/<row>/recipe.py).
"""

from pathlib import Path

from ocplace.experiments.experiment import DatasetSizes, EvalPlan, Experiment, TaskCpus
from ocplace.methods.registry import recipe_presets
from ocplace.models import offline_recipes
from ocplace.vocabulary import TEST_SUBSETS


def get_config() -> Experiment:
    return Experiment(
        name="demo",
        out=Path("out/demo"),
        seed=0,
        dataset=DatasetSizes(train_scenes=200, test_scenes=40, physical_scenes=10, seed=0),
        backbone=offline_recipes.demo_config(),  # the default architecture, 100 scenes, 75 steps
        recipes=recipe_presets("demo"),  # each learning row's PRESETS["demo"], in methods/<row>/recipe.py
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
