"""The experiments of `ocplace.configs`: one per scale, each complete and valid."""

import dataclasses

import pytest

from ocplace import configs
from ocplace.errors import UnknownExperiment
from ocplace.methods.registry import method_specs
from ocplace.models.offline_recipes import output_dir, recipe_dir
from ocplace.train.schedule import Schedule


@pytest.mark.parametrize("name", list(configs.EXPERIMENTS))
def test_each_experiment_is_named_after_its_scale_and_its_recipes_are_valid(name):
    experiment = configs.get(name)
    assert experiment.name == name
    recipes = experiment.recipes
    for config in (recipes.ours, recipes.ours_paper, recipes.no_llm, recipes.no_pretrain):
        config.validate()
    for config in (recipes.grids.schedule, recipes.cliport.schedule):
        config.validate()
    experiment.backbone.validate()
    experiment.validate()
    assert experiment.evaluation.unknown_methods(method_specs()) == []
    # `reproduce` pretrains into the folder that the backbone spec `offline:NAME` loads from.
    assert output_dir(experiment.backbone) == recipe_dir(name)


def test_ours_recipes_by_scale():
    default, demo, smoke = (configs.get(name).recipes.ours for name in ("default", "demo", "smoke"))
    assert default.schedule.steps == 200_000 and default.schedule.batch_size == 1
    assert smoke.schedule.steps < demo.schedule.steps < 200_000


@pytest.mark.parametrize("name", list(configs.EXPERIMENTS))
def test_ours_has_rule_a_adapters_and_the_paper_row_the_papers_at_the_same_budget(name):
    recipes = configs.get(name).recipes
    chosen, paper = recipes.ours.adapters, recipes.ours_paper.adapters
    assert (chosen.normalise, chosen.residual_ratio, chosen.text_ratio) == (True, 0.1, 0.5)
    assert (paper.normalise, paper.residual_ratio, paper.text_ratio) == (False, 0.2, None)
    assert (recipes.ours_paper.schedule.weight_decay, recipes.ours_paper.anchor) == (0.0, 0.0)
    assert recipes.ours.schedule == recipes.ours_paper.schedule


@pytest.mark.parametrize("name", list(configs.EXPERIMENTS))
def test_every_recipe_has_one_shape_and_leaves_seed_and_fraction_to_the_run(name):
    """A row's recipe: its model settings, one `Schedule` and its own extras; a run's seed and share of the
    training split come from its `TrainContext` (no recipe field of those names anywhere in the tree)."""

    def field_names(node) -> set[str]:
        fields = dataclasses.fields(node) if dataclasses.is_dataclass(node) else ()
        return {f.name for f in fields} | {n for f in fields for n in field_names(getattr(node, f.name))}

    recipes = configs.get(name).recipes
    for row in method_specs():
        recipe = recipes.of(row)
        if recipe is not None:
            assert isinstance(recipe.schedule, Schedule), row
            assert not {"seed", "fraction"} & field_names(recipe), row


def test_the_recipes_hold_one_field_per_learning_row_of_the_tree():
    """`MethodRecipes` is where a learning row is named beside its folder (typed, so the type checker holds each
    experiment's recipe to the row's `Recipe` and `--set` reaches it): no field without a row that learns, no
    learning row of `methods/` without a field."""
    from ocplace.experiments.experiment import MethodRecipes

    learning = {name for name, spec in method_specs().items() if spec.train is not None}
    assert {field.name for field in dataclasses.fields(MethodRecipes)} == learning


def test_a_method_finds_its_recipe_by_name():
    recipes = configs.get("smoke").recipes
    assert recipes.of("grids") is recipes.grids and recipes.of("no_pretrain") is recipes.no_pretrain
    assert recipes.of("no_adapter") is None  # learns nothing


def test_an_unknown_experiment_lists_the_choices():
    with pytest.raises(UnknownExperiment, match="unknown experiment 'huge'; choose one of smoke, demo, default"):
        configs.get("huge")


def test_the_clis_experiment_names_are_the_configs():
    """`vocabulary.EXPERIMENT_NAMES` restates `configs.EXPERIMENTS` so the CLI need not import the configs."""
    from ocplace.vocabulary import EXPERIMENT_NAMES

    assert tuple(configs.EXPERIMENTS) == EXPERIMENT_NAMES
