"""The experiments of `ocplace.configs`: one per scale, each complete and valid."""

import dataclasses
import importlib

import pytest

from ocplace import configs
from ocplace.errors import ConfigError, UnknownExperiment
from ocplace.methods.no_llm.recipe import NoLlmRecipe
from ocplace.methods.registry import method_specs, recipe_types, row_packages
from ocplace.models.offline_recipes import output_dir, recipe_dir
from ocplace.train.schedule import Schedule


@pytest.mark.parametrize("name", list(configs.EXPERIMENTS))
def test_each_experiment_is_named_after_its_scale_and_its_recipes_are_valid(name):
    experiment = configs.get(name)
    assert experiment.name == name
    recipes = experiment.recipes
    for config in (recipes["ours"], recipes["ours_paper"], recipes["no_llm"], recipes["no_pretrain"]):
        config.validate()
    for config in (recipes["grids"].schedule, recipes["cliport"].schedule):
        config.validate()
    experiment.backbone.validate()
    experiment.validate()
    assert experiment.evaluation.unknown_methods(method_specs()) == []
    # `reproduce` pretrains into the folder that the backbone spec `offline:NAME` loads from.
    assert output_dir(experiment.backbone) == recipe_dir(name)


def test_ours_recipes_by_scale():
    default, demo, smoke = (configs.get(name).recipes["ours"] for name in ("default", "demo", "smoke"))
    assert default.schedule.steps == 200_000 and default.schedule.batch_size == 1
    assert smoke.schedule.steps < demo.schedule.steps < 200_000


@pytest.mark.parametrize("name", list(configs.EXPERIMENTS))
def test_ours_has_rule_a_adapters_and_the_paper_row_the_papers_at_the_same_budget(name):
    recipes = configs.get(name).recipes
    chosen, paper = recipes["ours"].adapters, recipes["ours_paper"].adapters
    assert (chosen.normalise, chosen.residual_ratio, chosen.text_ratio) == (True, 0.1, 0.5)
    assert (paper.normalise, paper.residual_ratio, paper.text_ratio) == (False, 0.2, None)
    assert (recipes["ours_paper"].schedule.weight_decay, recipes["ours_paper"].anchor) == (0.0, 0.0)
    assert recipes["ours"].schedule == recipes["ours_paper"].schedule


@pytest.mark.parametrize("name", list(configs.EXPERIMENTS))
def test_every_recipe_has_one_shape_and_leaves_seed_and_fraction_to_the_run(name):
    """A row's recipe: its model settings, one `Schedule` and its own extras; a run's seed and share of the
    training split come from its `TrainContext` (no recipe field of those names anywhere in the tree)."""

    def field_names(node) -> set[str]:
        fields = dataclasses.fields(node) if dataclasses.is_dataclass(node) else ()
        return {f.name for f in fields} | {n for f in fields for n in field_names(getattr(node, f.name))}

    experiment = configs.get(name)
    for row in method_specs():
        recipe = experiment.recipe(row)
        if recipe is not None:
            assert isinstance(recipe.schedule, Schedule), row
            assert not {"seed", "fraction"} & field_names(recipe), row


@pytest.mark.parametrize("name", list(configs.EXPERIMENTS))
def test_each_experiment_holds_a_recipe_for_every_learning_row_of_its_registered_type(name):
    """The recipes are keyed by the rows' registered names and typed by each row's `RECIPE`: no entry without a
    row that learns with one, no such row without an entry, each of its row's type."""
    experiment = configs.get(name)
    types = recipe_types()
    learning = {row for row, spec in method_specs().items() if spec.train is not None and row in types}
    assert set(experiment.recipes) == learning == set(types)
    assert all(type(experiment.recipes[row]) is types[row] for row in learning)
    assert experiment.missing_recipes(method_specs()) == []
    # One place per setting (issue 61): every recipe value is its row's preset for this experiment, none restated.
    packages = {row: importlib.import_module(package) for row, package in row_packages().items() if row in learning}
    assert {row: package.PRESETS[name] for row, package in packages.items()} == dict(experiment.recipes)


def test_a_row_finds_its_recipe_by_name_and_a_missing_or_foreign_one_is_named():
    experiment = configs.get("smoke")
    assert experiment.recipe("grids") is experiment.recipes["grids"]
    assert experiment.recipe("no_adapter") is None  # learns nothing
    without = dataclasses.replace(experiment, recipes={k: v for k, v in experiment.recipes.items() if k != "grids"})
    assert without.missing_recipes(["ours", "grids", "no_adapter"]) == [
        "recipes has no entry for grids, which learns with a GridsRecipe: add one to the experiment"
    ]
    # A row of the tree needs its entry even when its recipe has defaults (a row from outside falls back on them).
    no_llm_left_out = dataclasses.replace(
        experiment, recipes={k: v for k, v in experiment.recipes.items() if k != "no_llm"}
    )
    assert no_llm_left_out.missing_recipes(["no_llm"]) and no_llm_left_out.recipe("no_llm") == NoLlmRecipe()
    swapped = dataclasses.replace(experiment, recipes={**experiment.recipes, "grids": experiment.recipes["cliport"]})
    with pytest.raises(ConfigError, match="recipes.grids is a CliportRecipe; grids learns with a GridsRecipe"):
        swapped.validate()
    stray = dataclasses.replace(experiment, recipes={**experiment.recipes, "no_adapter": experiment.recipes["ours"]})
    with pytest.raises(ConfigError, match="recipes.no_adapter names no row that learns with a recipe"):
        stray.validate()


def test_an_unknown_experiment_lists_the_choices():
    with pytest.raises(UnknownExperiment, match="unknown experiment 'huge'; choose one of smoke, demo, default"):
        configs.get("huge")


def test_the_clis_experiment_names_are_the_configs():
    """`vocabulary.EXPERIMENT_NAMES` restates `configs.EXPERIMENTS` so the CLI need not import the configs."""
    from ocplace.vocabulary import EXPERIMENT_NAMES

    assert tuple(configs.EXPERIMENTS) == EXPERIMENT_NAMES
