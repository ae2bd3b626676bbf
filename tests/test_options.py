"""Flags generated from config dataclasses and `--set KEY=VALUE` overrides (ocplace/cli/options.py)."""

from __future__ import annotations

import argparse
import dataclasses
import math
import re
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Literal

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ocplace import configs
from ocplace.cli.options import (
    add_config_arguments,
    apply_overrides,
    config_from_arguments,
    describe,
    format_value,
    parse_value,
)
from ocplace.errors import ConfigError, OcplaceError
from ocplace.methods.ours.recipe import OursRecipe, smoke_config
from ocplace.train.schedule import rescheduled


@dataclasses.dataclass(frozen=True)
class Inner:
    rate: float = 0.5
    name: str = "inner"
    shares: tuple[tuple[str, float], ...] = (("object", 0.5), ("primitive", 0.5))


@dataclasses.dataclass(frozen=True)
class Leaves:
    count: int = 3
    rate: float = dataclasses.field(default=1e-3, metadata={"help": "how fast"})
    name: str = "leaves"
    path: Path = Path("out")
    flag: bool = True
    limit: int | None = None
    folder: Path | None = None
    sizes: tuple[int, ...] = (1, 2)
    names: tuple[str, ...] = ("a", "b")
    pair: tuple[str, float] = ("x", 1.0)
    kind: Literal["small", "large"] = "small"
    inner: Inner = Inner()


@dataclasses.dataclass(frozen=True)
class Root:
    seed: int = 0
    leaves: Leaves = Leaves()
    maybe: Inner | None = None


# Text a value of each field can be written as: no separators, no edge spaces, not "none".
WORDS = st.text(st.characters(codec="utf-8", exclude_characters=",:\x00"), min_size=1).filter(
    lambda text: text == text.strip() and text.lower() != "none"
)
FLOATS = st.floats(allow_nan=False, allow_infinity=False, width=64)  # --set refuses what is not finite
VALUES = {
    "count": st.integers(),
    "rate": FLOATS,
    "name": WORDS,
    "path": WORDS.map(Path),
    "flag": st.booleans(),
    "limit": st.none() | st.integers(),
    "folder": st.none() | WORDS.map(Path),
    "sizes": st.tuples() | st.lists(st.integers(), min_size=1).map(tuple),
    "names": st.lists(WORDS, min_size=1).map(tuple),
    "pair": st.tuples(WORDS, FLOATS),
    "kind": st.sampled_from(["small", "large"]),
    "inner.rate": FLOATS,
    "inner.name": WORDS,
    "inner.shares": st.lists(st.tuples(WORDS, FLOATS), min_size=1).map(tuple),
}


def _get(config, key: str):
    for name in key.split("."):
        config = config[name] if isinstance(config, Mapping) else getattr(config, name)
    return config


def _leaf_keys(config, prefix: str = ""):
    """Every dotted key of a setting (not a group) in a tree of dataclasses and mappings of them."""
    items = (
        config.items()
        if isinstance(config, Mapping)
        else ((f.name, getattr(config, f.name)) for f in dataclasses.fields(config))
    )
    for name, value in items:
        if dataclasses.is_dataclass(value) or isinstance(value, Mapping):
            yield from _leaf_keys(value, f"{prefix}{name}.")
        else:
            yield prefix + name


def test_the_strategies_cover_every_setting():
    assert set(VALUES) == set(_leaf_keys(Leaves()))


# The value strategies are built lazily on their first draw, which takes over a second when the 2-core
# machine is busy; Hypothesis's too_slow check would then measure the machine, not these tests.
SETTINGS = settings(suppress_health_check=[HealthCheck.too_slow])


@SETTINGS
@given(st.data())
def test_every_field_type_round_trips_through_set(data):
    root = Root()
    key = data.draw(st.sampled_from(sorted(VALUES)))
    value = data.draw(VALUES[key])
    changed = apply_overrides(root, [f"leaves.{key}={format_value(value)}"])
    assert _get(changed, f"leaves.{key}") == value
    assert type(_get(changed, f"leaves.{key}")) is type(value)
    assert root == Root()  # the original is untouched
    assert changed == apply_overrides(changed, [f"leaves.{key}={format_value(value)}"])


@SETTINGS
@given(st.data())
def test_overrides_apply_in_order_and_the_last_one_wins(data):
    expected, overrides = {}, []
    for key in data.draw(st.lists(st.sampled_from(sorted(VALUES)), max_size=6)):
        expected[key] = data.draw(VALUES[key])
        overrides.append(f"leaves.{key}={format_value(expected[key])}")
    changed = apply_overrides(Root(), overrides)
    for key, value in expected.items():
        assert _get(changed, f"leaves.{key}") == value
    untouched = set(VALUES) - set(expected)
    assert all(_get(changed, f"leaves.{key}") == _get(Root(), f"leaves.{key}") for key in untouched)


def test_set_refuses_a_number_that_is_not_finite():
    for text in ("inf", "-inf", "nan"):
        with pytest.raises(ConfigError, match=f"--set leaves.rate={text}: {text} is not a finite number"):
            apply_overrides(Root(), [f"leaves.rate={text}"])


def test_the_result_is_a_new_frozen_config_of_the_same_types():
    root = Root()
    changed = apply_overrides(root, ["leaves.inner.rate=2", "seed=7"])
    assert type(changed) is Root and type(changed.leaves.inner) is Inner
    assert (changed.seed, changed.leaves.inner.rate, root.seed, root.leaves.inner.rate) == (7, 2.0, 0, 0.5)
    assert changed.leaves.inner.name == "inner" and changed.leaves.count == 3
    with pytest.raises(dataclasses.FrozenInstanceError):
        changed.leaves.inner.rate = 3.0
    assert apply_overrides(root, []) is root


@pytest.mark.parametrize(
    "text, hint, value",
    [
        ("none", int | None, None),
        (" None ", Path | None, None),
        ("TRUE", bool, True),
        (" false", bool, False),
        ("", tuple[int, ...], ()),
        ("1, 2 ,3", tuple[int, ...], (1, 2, 3)),
        ("object:0.5, primitive : 0.25", tuple[tuple[str, float], ...], (("object", 0.5), ("primitive", 0.25))),
        ("1e-4", float, 1e-4),
        ("-inf", float, -math.inf),
        ("200_000", int, 200_000),
        ("large", Literal["small", "large"], "large"),
        ("none", tuple[str, ...] | None, None),
    ],
)
def test_values_parse_by_annotation(text, hint, value):
    assert parse_value(text, hint) == value


@pytest.mark.parametrize(
    "override, message",
    [
        ("leaves.count=1.5", "leaves.count=1.5: expected an integer, got '1.5'"),
        ("leaves.count=none", "expected an integer, got 'none'"),
        ("leaves.limit=many", "expected an integer or none, got 'many'"),
        ("leaves.rate=fast", "expected a number"),
        ("leaves.flag=yes", "expected true or false, got 'yes'"),
        ("leaves.sizes=1,a", "expected an integer, got 'a'"),
        ("leaves.pair=x", "expected 2 items separated by ','"),
        ("leaves.inner.shares=object", "expected 2 items separated by ':'"),
        ("leaves.kind=medium", "expected one of small, large, got 'medium'"),
    ],
)
def test_bad_values_name_the_key_and_the_expected_type(override, message):
    with pytest.raises(ConfigError, match=re.escape(message)):
        apply_overrides(Root(), [override])


@pytest.mark.parametrize(
    "override, message",
    [
        ("sede=1", "unknown key 'sede': valid keys at the top level are seed, leaves.*, maybe"),
        ("leaves.inner.speed=1", "valid keys under 'leaves.inner' are rate, name, shares"),
        ("leaves.count.value=1", "unknown key 'leaves.count.value': leaves.count is a value"),
        ("maybe.rate=1", "maybe is a value"),  # an unset optional group has no keys to set
        ("leaves.inner=1", "'leaves.inner' names a group of settings; set one of its keys: leaves.inner.rate"),
        ("seed", "--set takes KEY=VALUE, got 'seed'"),
        ("=1", "--set takes KEY=VALUE"),
    ],
)
def test_unknown_keys_name_the_valid_ones(override, message):
    with pytest.raises(ConfigError, match=re.escape(message)) as caught:
        apply_overrides(Root(), [override])
    assert isinstance(caught.value, OcplaceError)


def test_a_value_may_hold_equals_signs():
    assert apply_overrides(Root(), ["leaves.name=a=b"]).leaves.name == "a=b"


def test_every_setting_of_every_experiment_and_training_config_round_trips():
    for config in (OursRecipe(), smoke_config(), *(configs.get(name) for name in configs.EXPERIMENTS)):
        for key in _leaf_keys(config):
            assert apply_overrides(config, [f"{key}={format_value(_get(config, key))}"]) == config, key


def test_an_experiment_takes_nested_overrides():
    experiment = configs.get("smoke")
    changed = apply_overrides(
        experiment, ["recipes.ours.schedule.steps=5000", "dataset.train_scenes=100", "evaluation.methods=ours, grids"]
    )
    assert changed == dataclasses.replace(
        experiment,
        recipes={**experiment.recipes, "ours": rescheduled(experiment.recipes["ours"], steps=5000)},
        dataset=dataclasses.replace(experiment.dataset, train_scenes=100),
        evaluation=dataclasses.replace(experiment.evaluation, methods=("ours", "grids")),
    )
    valid = "valid keys under 'recipes' are ours.*, ours_paper.*, grids.*, cliport.*, no_llm.*, no_pretrain.*"
    with pytest.raises(ConfigError, match=re.escape(valid)):
        apply_overrides(experiment, ["recipes.oursx.steps=1"])
    with pytest.raises(
        ConfigError, match=re.escape("'recipes' names a group of settings; set one of its keys: recipes.ours.*")
    ):
        apply_overrides(experiment, ["recipes=1"])
    with pytest.raises(
        ConfigError,
        match=re.escape("'recipes.grids' names a group of settings; set one of its keys: recipes.grids.grid"),
    ):
        apply_overrides(experiment, ["recipes.grids=1"])


# --- generated flags -------------------------------------------------------------------------


def _parser(**options) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(exit_on_error=False)
    add_config_arguments(parser, Leaves, **options)
    return parser


def test_flags_are_generated_for_every_setting_but_groups():
    flags = {action.dest: action.option_strings for action in _parser()._actions if action.dest != "help"}
    assert set(flags) == {field.name for field in dataclasses.fields(Leaves)} - {"inner"}
    assert flags["count"] == ["--count"] and flags["flag"] == ["--flag", "--no-flag"]
    assert all(value is None for value in vars(_parser().parse_args([])).values())


def test_flags_left_out_keep_the_base_values():
    base = Leaves(count=9, flag=False, limit=4)
    assert config_from_arguments(_parser().parse_args([]), base) == base


def test_given_flags_replace_the_base_values():
    args = _parser().parse_args(
        ["--count", "5", "--flag", "--limit", "7", "--folder", "runs", "--sizes", "3,4", "--pair", "y,2", "--rate=1"]
    )
    assert config_from_arguments(args, Leaves(flag=False)) == Leaves(
        count=5, flag=True, limit=7, folder=Path("runs"), sizes=(3, 4), pair=("y", 2.0), rate=1.0
    )
    assert config_from_arguments(_parser().parse_args(["--no-flag"]), Leaves()).flag is False


def test_only_the_chosen_fields_get_flags_and_are_applied():
    parser = _parser(fields=("count",), aliases={"count": ("-n", "--number")})
    args = parser.parse_args(["--number", "4"])
    args.rate = 9.0  # another option of the same name is not the config's
    assert config_from_arguments(args, Leaves(), fields=("count",)) == Leaves(count=4)
    with pytest.raises(TypeError, match="has no field"):
        _parser(fields=("counts",))
    with pytest.raises(TypeError, match="no command-line form"):
        _parser(fields=("inner",))  # a group is set key by key, with --set


def test_a_bad_flag_value_is_a_usage_error_naming_the_type():
    with pytest.raises(argparse.ArgumentError, match="expected an integer, got 'x'"):
        _parser().parse_args(["--count", "x"])
    with pytest.raises(argparse.ArgumentError, match="expected an integer, got 'none'"):
        _parser().parse_args(["--limit", "none"])  # left out means "keep", so a flag cannot set None


def test_help_comes_from_the_metadata_then_the_type_with_the_default():
    text = _parser().format_help()
    assert "how fast (default: 0.001)" in text
    assert "items separated by ',', each an integer (default: 1,2)" in text


def test_unsupported_types_fail_when_the_parser_is_built():
    @dataclasses.dataclass(frozen=True)
    class Odd:
        table: dict = dataclasses.field(default_factory=dict)

    with pytest.raises(TypeError, match="no command-line form"):
        add_config_arguments(argparse.ArgumentParser(), Odd)
    with pytest.raises(TypeError, match="no command-line form"):
        describe(typing.get_type_hints(Odd)["table"])


def test_old_flags_work_for_one_release_and_say_what_to_use(capsys, tmp_path):
    """`--scale`, `--data` and the positional dataset folder: the new flag's value, a deprecation message."""
    from ocplace.cli import build_parser
    from ocplace.cli.options import dataset_of

    parser = build_parser()
    cases = [
        (["reproduce", "--scale", "smoke"], "experiment", "smoke", "--experiment"),
        (["evaluate", "--scale", "demo"], "experiment", "demo", "--experiment"),
        (["backbone", "eval", "--data", str(tmp_path)], "dataset", tmp_path, "--dataset DIR"),
    ]
    for argv, dest, value, instead in cases:
        assert getattr(parser.parse_args(argv), dest) == value
        assert f"deprecated and goes in the next release; use {instead}" in capsys.readouterr().err
    old = parser.parse_args(["dataset", "verify", str(tmp_path)])
    assert dataset_of(old) == tmp_path and "use --dataset DIR" in capsys.readouterr().err
    new = parser.parse_args(["dataset", "verify", "--dataset", str(tmp_path)])
    assert dataset_of(new) == tmp_path and capsys.readouterr().err == ""
    assert parser.parse_args(["reproduce", "--experiment", "smoke"]).experiment == "smoke"
    assert capsys.readouterr().err == ""
    with pytest.raises(ConfigError, match="--dataset DIR"):
        dataset_of(parser.parse_args(["dataset", "verify"]))


def _every_action(parser: argparse.ArgumentParser, path: str):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _every_action(sub, f"{path} {name}")
        elif not isinstance(action, argparse._HelpAction):
            yield path, action


def test_every_flag_of_every_command_has_help():
    from ocplace.cli import build_parser

    actions = list(_every_action(build_parser(), "ocplace"))
    assert len(actions) > 200  # every subcommand was walked
    assert [f"{path} {'/'.join(a.option_strings) or a.dest}" for path, a in actions if not a.help] == []


def test_train_shows_the_defaults_a_run_records():
    from ocplace.cli import build_parser
    from ocplace.methods.ours.recipe import default_config

    ours = default_config()
    recorded = dataclasses.asdict(ours.adapters) | dataclasses.asdict(ours.schedule) | dataclasses.asdict(ours)
    shown = {
        a.dest: re.search(r"\(default: ([^)]*)\)$", a.help)[1]
        for path, a in _every_action(build_parser(), "ocplace")
        if path == "ocplace train" and a.dest in recorded and "(default: " in (a.help or "")
    }
    assert shown["residual_ratio"] == "0.1" and shown["text_ratio"] == "0.5" and shown["normalise"] == "true"
    assert len(shown) >= 14 and all(text == format_value(recorded[name]) for name, text in shown.items()), shown


@pytest.mark.parametrize("text", ["1e9", "1e300", "86401", "inf", "nan", "-1"])
def test_a_duration_beyond_a_day_or_not_a_number_is_refused_before_work(text, capsys):
    from ocplace.cli import main

    with pytest.raises(SystemExit):  # argparse's usage error: nothing ran
        main(["evaluate", "--dataset", "nowhere", "--out", "r.json", "--policy", "m:f", "--scene-timeout", text])
    assert "--scene-timeout" in capsys.readouterr().err


def test_a_day_is_the_longest_duration():
    from ocplace.cli.options import MAX_DURATION_S, seconds

    assert seconds("86400") == MAX_DURATION_S and seconds("0") == 0.0 and seconds("2.5") == 2.5


def _numeric(action: argparse.Action) -> bool:
    """Whether the flag reads a number (its type turns "1", "50" or "0.5" into one)."""
    for text in ("1", "50", "0.5"):
        try:
            if callable(action.type) and isinstance(action.type(text), int | float):
                return True
        except (argparse.ArgumentTypeError, ValueError, TypeError):
            continue
    return False


def test_every_numeric_flag_of_every_command_is_bounded_as_it_is_read():
    """Issue 60, item 6: no numeric flag takes a huge, infinite, NaN or (but for its one "all" value, -1) negative
    number to fail later, per scene or in the middle of the work: each is refused as the flag is read."""
    from ocplace.cli import build_parser

    numeric = [(path, action) for path, action in _every_action(build_parser(), "ocplace") if _numeric(action)]
    assert len(numeric) > 40
    accepted = []
    for path, action in numeric:
        for text in ("1e300", "99999999999999999999", "inf", "nan", "-5"):
            try:
                action.type(text)
            except (argparse.ArgumentTypeError, ValueError):
                continue
            accepted.append(f"{path} {'/'.join(action.option_strings)} {text}")
    assert accepted == []


@pytest.mark.parametrize("out", [".", "..", "a_folder", "a_folder/", "taken.json"])
def test_evaluate_checks_its_out_before_any_work(out, tmp_path, monkeypatch, capsys):
    """Issue 60, item 7: `--out .`, `..`, an existing folder, or a file where the store goes: refused at once,
    nothing written."""
    from ocplace.cli import main

    monkeypatch.chdir(tmp_path)
    (tmp_path / "a_folder").mkdir()
    (tmp_path / "taken.evaluations").write_text("a file where the store would go")
    before = sorted(p.name for p in tmp_path.iterdir())
    assert main(["evaluate", "--dataset", str(tmp_path), "--out", out, "--methods", "no_adapter"]) == 2
    err = capsys.readouterr().err
    assert ("is a folder; give the results file" in err) or ("where --out taken.json keeps" in err), err
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_reproduce_checks_every_output_path_before_any_work(tmp_path, capsys):
    """Issue 60, item 7: a file where `reproduce` puts a folder, a folder where it puts a file, OUT inside its own
    dataset: all named in one refusal, before the library, the dataset or any run is touched."""
    from ocplace.cli import main

    out = tmp_path / "out"
    (out / "results.json").mkdir(parents=True)
    (out / "runs").write_text("a file where the runs go")
    before = sorted(str(p.relative_to(tmp_path)) for p in tmp_path.rglob("*"))
    assert main(["reproduce", "--experiment", "smoke", "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert f"{out / 'results.json'} is a folder, where a file goes" in err, err
    assert f"{out / 'runs'} is a file, where a folder goes" in err, err
    inside = ["reproduce", "--experiment", "smoke", "--dataset", str(tmp_path), "--out", str(tmp_path / "o")]
    assert main(inside) == 2
    assert "is the dataset" in capsys.readouterr().err
    assert sorted(str(p.relative_to(tmp_path)) for p in tmp_path.rglob("*")) == before


def test_a_method_named_twice_is_refused_before_any_work(tmp_path, capsys):
    """Issue 60: `--methods no_adapter,no_adapter` evaluated the row twice and showed it in two equal rows."""
    from ocplace.cli import main

    command = ["evaluate", "--dataset", str(tmp_path), "--methods", "no_adapter,ours,no_adapter"]
    assert main([*command, "--out", str(tmp_path / "r.json")]) == 2
    assert "--methods names no_adapter twice; name each method once" in capsys.readouterr().err
    assert main(["reproduce", "--experiment", "smoke", "--methods", "ours,ours", "--out", str(tmp_path / "o")]) == 2
    assert "evaluation.methods names ours twice" in capsys.readouterr().err
    assert sorted(tmp_path.iterdir()) == []
