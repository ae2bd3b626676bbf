"""The one serialiser (`ocplace.serial`): every config and record dataclass round-trips by its type hints,
and the canonical text is the one caches and run files were keyed by before it existed."""

import dataclasses
import json

import pytest

from ocplace import configs, serial
from ocplace.errors import ConfigError
from ocplace.eval.harness import EvalSettings, PhysicalOutcome, SceneOutcome
from ocplace.experiments.experiment import Experiment
from ocplace.methods.cliport.model import CliportConfig
from ocplace.methods.grids.model import GridConfig
from ocplace.methods.no_llm.model import NoLlmConfig
from ocplace.methods.ours.recipe import OursRecipe
from ocplace.models import offline_config
from ocplace.models.backbone import PromptConfig
from ocplace.models.offline_recipes import PretrainConfig

EXPERIMENTS = [configs.get(name) for name in configs.EXPERIMENTS]


@pytest.mark.parametrize("experiment", EXPERIMENTS, ids=lambda e: e.name)
def test_every_experiment_round_trips_through_json_text(experiment):
    assert serial.from_json(type(experiment), serial.to_json(experiment)) == experiment
    recipes = experiment.recipes
    for config in (
        recipes["ours"],
        recipes["no_llm"],
        recipes["no_pretrain"],
        recipes["grids"],
        recipes["cliport"],
        experiment.backbone,
    ):
        assert serial.from_dict(type(config), json.loads(serial.to_json(config))) == config


def test_a_recipe_of_no_registered_row_is_not_read_back():
    text = json.loads(serial.to_json(configs.get("smoke")))
    text["recipes"]["toy_row"] = {}
    with pytest.raises(ConfigError, match="recipes holds toy_row, no registered row that learns with a recipe"):
        serial.from_dict(Experiment, text)


@pytest.mark.parametrize(
    "config",
    [OursRecipe(), PromptConfig(), NoLlmConfig(dim=32), GridConfig(), CliportConfig(), EvalSettings()],
    ids=lambda c: type(c).__name__,
)
def test_the_text_is_what_dataclasses_asdict_gave(config):
    """Caches, feature files and run metadata hash this text: it must not change under them."""
    assert serial.to_json(config) == json.dumps(dataclasses.asdict(config), sort_keys=True)


def test_an_efficientnet_trunk_leaves_the_vit_depth_out_of_its_text():
    lite, vit = offline_config.default_config(), offline_config.vit_config()
    assert not {"layers", "heads", "mlp_dim"} & set(serial.to_dict(lite))
    assert {"layers", "heads", "mlp_dim"} <= set(serial.to_dict(vit))
    assert serial.to_dict(dataclasses.replace(lite, layers=99)) == serial.to_dict(lite)
    recipe = configs.get("smoke").backbone
    assert serial.from_dict(PretrainConfig, serial.to_dict(recipe)) == recipe


def test_a_scene_outcome_comes_back_with_its_tuples_and_nested_outcome():
    outcome = SceneOutcome(
        "seen-00001",
        "2obj",
        True,
        0.5,
        (0.1, -0.2),
        16,
        None,
        (("mug", "left of"), ("shoe", "behind")),
        (3, 0),
        True,
        True,
        True,
        None,
        PhysicalOutcome(True, True, 0.01, 0.002),
        None,
    )
    again = serial.from_dict(SceneOutcome, json.loads(serial.to_json(outcome)))
    assert again == outcome and isinstance(again.parsed[0], tuple) and isinstance(again.physical, PhysicalOutcome)
    failed = dataclasses.replace(outcome, mode=None, parsed=None, grounded=None, physical=None, failure="X: why")
    assert serial.from_dict(SceneOutcome, json.loads(serial.to_json(failed))) == failed
