"""Command-line options derived from frozen config dataclasses, so flags and configs cannot drift apart.

`add_config_arguments` turns fields into `--field-name` flags and `config_from_arguments` applies the
ones given; `apply_overrides` applies `--set KEY=VALUE` items on dotted paths into nested configs.

Why argparse and not tyro: the whole CLI is argparse subcommands whose modules import heavy
libraries (JAX, MuJoCo) only inside their handlers, so that `ocplace --help` stays instant. These
helpers add flags to those existing parsers and import only the standard library; a config class
is imported at registration only where its module is as light (`ocplace.methods.ours.recipe`).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import types
import typing
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from ocplace import serial
from ocplace.errors import ConfigError
from ocplace.vocabulary import MAX_SEED as MAX_SEED  # a flag's bound, as a recipe's

_BOOLS = {"true": True, "false": False}
_SEPARATORS = (",", ":")  # between a tuple's items, and between the items of a tuple inside it
_DESCRIPTIONS = {int: "an integer", float: "a number", str: "a string", Path: "a path", bool: "true or false"}


def add_config_arguments(
    parser: argparse.ArgumentParser | argparse._ArgumentGroup,
    config_cls: type,
    fields: Sequence[str] | None = None,
    aliases: Mapping[str, Sequence[str]] | None = None,
    defaults: object | None = None,
) -> None:
    """Adds `--field-name` for each of `fields` (default: every field a flag can hold) of `config_cls`.

    Every flag defaults to None, meaning "keep the base configuration's value" (so an optional field's
    flag cannot set None: `--set` can); a bool field gets `--name/--no-name`, a tuple one takes
    comma-separated items. `aliases` maps a field to extra flag names. Help comes from
    `dataclasses.field(metadata={"help": ...})` or the type, followed by the default: the value in `defaults` (the
    base configuration a run starts from and records), else the class's.
    """
    hints = typing.get_type_hints(config_cls)
    for field in _selected_fields(config_cls, hints, fields):
        flags = ["--" + field.name.replace("_", "-"), *(aliases or {}).get(field.name, ())]
        hint = _unwrap_optional(hints[field.name])[1]  # a flag left out already means "keep", so no `none`
        default = getattr(defaults, field.name) if defaults is not None else field.default
        help_text = _help(field, hint, default)
        if hint is bool:
            parser.add_argument(
                *flags, dest=field.name, action=argparse.BooleanOptionalAction, default=None, help=help_text
            )
        else:
            bounds = field.metadata.get(serial.BOUNDS)
            parser.add_argument(*flags, dest=field.name, type=_flag_parser(hint, bounds), help=help_text)


def config_from_arguments(args: argparse.Namespace, base_config, fields: Sequence[str] | None = None):
    """`base_config` with every flag of `add_config_arguments(..., type(base_config), fields)` that was given."""
    hints = typing.get_type_hints(type(base_config))
    names = [field.name for field in _selected_fields(type(base_config), hints, fields)]
    return dataclasses.replace(
        base_config, **{name: getattr(args, name) for name in names if getattr(args, name, None) is not None}
    )


def add_set_argument(parser: argparse.ArgumentParser | argparse._ArgumentGroup, example: str) -> None:
    """`--set KEY=VALUE` (repeatable, into `overrides`): any setting of the experiment, `apply_overrides`' input."""
    parser.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="set any setting of the experiment (ocplace.configs); KEY is a dotted path such as "
        f"{example}, an unknown one lists the valid keys (repeatable; see docs/evaluation.md)",
    )


def apply_overrides(config, overrides: Iterable[str]):
    """`config` with each `KEY=VALUE` applied in order; KEY is a dotted path into nested frozen dataclasses.

    VALUE is parsed by the field's annotation (see `parse_value`). Raises ConfigError, naming the
    valid keys, for an unknown key, and naming the expected type for a value that does not parse.
    """
    for item in overrides:
        key, sep, text = item.partition("=")
        if not sep or not key.strip():
            raise ConfigError(f"--set takes KEY=VALUE, got {item!r}")
        config = _set(config, key.strip().split("."), text, key.strip())
    return config


def parse_value(text: str, hint):
    """`text` as a value of type `hint`: int, float, str, Path, bool (true/false), `X | None` (none),
    a Literal, or a tuple of those (items separated by commas and stripped, an empty text being the
    empty tuple; items of a tuple inside a tuple separated by colons: `object:0.5,primitive:0.5`).
    Raises ValueError saying what was expected."""
    return _parse(text, hint, 0)


def format_value(value) -> str:
    """The text `parse_value` reads back as `value` (given strings without separators or edge spaces)."""
    return _format(value, 0)


def describe(hint) -> str:
    """What a value of type `hint` looks like, for messages: "an integer", "comma-separated items, ..."."""
    return _describe(hint, 0)


def _parse(text: str, hint, depth: int):
    optional, inner = _unwrap_optional(hint)
    if optional and text.strip().lower() == "none":
        return None
    origin = typing.get_origin(inner)
    if origin is tuple:
        return _parse_tuple(text, typing.get_args(inner), depth)
    if origin is typing.Literal:
        for choice in typing.get_args(inner):
            if str(choice) == text:
                return choice
        raise ValueError(f"expected {describe(hint)}, got {text!r}")
    if inner not in _DESCRIPTIONS:
        raise TypeError(f"no command-line form for type {hint!r}")
    try:
        if inner is bool:
            return _BOOLS[text.strip().lower()]
        if inner is Path and not text.strip():
            raise ValueError  # Path("") is the current folder: never what an empty value meant
        return inner(text)
    except (KeyError, ValueError):
        raise ValueError(f"expected {describe(hint)}, got {text!r}") from None


def _parse_tuple(text: str, items: tuple, depth: int) -> tuple:
    separator = _separator(depth)
    parts = [part.strip() for part in text.split(separator)] if text.strip() else []
    if _is_variadic(items):
        return tuple(_parse(part, items[0], depth + 1) for part in parts)
    if len(parts) != len(items):
        raise ValueError(f"expected {len(items)} items separated by {separator!r}, got {text!r}")
    return tuple(_parse(part, hint, depth + 1) for part, hint in zip(parts, items, strict=True))


def _format(value, depth: int) -> str:
    if value is None:
        return "none"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, tuple):
        return _separator(depth).join(_format(item, depth + 1) for item in value)
    return str(value)


def _describe(hint, depth: int) -> str:
    optional, inner = _unwrap_optional(hint)
    origin = typing.get_origin(inner)
    if origin is tuple:
        items, separator = typing.get_args(inner), _separator(depth)
        if _is_variadic(items):
            text = f"items separated by {separator!r}, each {_describe(items[0], depth + 1)}"
        else:
            kinds = "; ".join(_describe(item, depth + 1) for item in items)
            text = f"{len(items)} items separated by {separator!r} ({kinds})"
    elif origin is typing.Literal:
        text = "one of " + ", ".join(map(str, typing.get_args(inner)))
    elif inner in _DESCRIPTIONS:
        text = _DESCRIPTIONS[inner]
    else:
        raise TypeError(f"no command-line form for type {hint!r}")
    return text + " or none" if optional else text


def _separator(depth: int) -> str:
    if depth >= len(_SEPARATORS):
        raise TypeError(f"no command-line form for tuples nested deeper than {len(_SEPARATORS)}")
    return _SEPARATORS[depth]


def _is_variadic(items: tuple) -> bool:
    return len(items) == 2 and items[1] is Ellipsis


def _selected_fields(config_cls: type, hints: dict, names: Sequence[str] | None) -> list[dataclasses.Field]:
    fields = {field.name: field for field in dataclasses.fields(config_cls) if field.init}
    if names is None:
        return [field for field in fields.values() if not _is_group(hints[field.name])]
    unknown = [name for name in names if name not in fields]
    if unknown:
        raise TypeError(f"{config_cls.__name__} has no field(s) {', '.join(unknown)}")
    return [fields[name] for name in names]


def _flag_parser(hint, bounds=None):
    describe(hint)  # an unsupported type fails when the parser is built, not when a user passes the flag

    def parse(text: str):
        try:
            return within(parse_value(text, hint), bounds)
        except ValueError as error:
            raise argparse.ArgumentTypeError(str(error)) from None

    return parse


def within(value, bounds):
    """`value` when it is not a number, or a finite one inside `bounds` (a field's `serial.BOUNDS`); ValueError
    naming the range otherwise."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return value
    if not math.isfinite(value):
        raise ValueError(f"{value} is not a finite number")
    if bounds is not None and not bounds[0] <= value <= bounds[1]:
        raise ValueError(f"{value:g} is out of range: give a number from {_shown(bounds[0])} to {_shown(bounds[1])}")
    return value


def _shown(bound: float) -> str:
    return f"{bound:,}" if isinstance(bound, int) else f"{bound:g}"


def _help(field: dataclasses.Field, hint, default: object) -> str:
    text = field.metadata.get("help", describe(hint))
    if default is not dataclasses.MISSING:
        text += f" (default: {format_value(default)})"
    return text.replace("%", "%%")  # argparse %-formats help


def _set(node: Any, path: list[str], text: str, key: str) -> Any:
    """`node` (a dataclass, or a mapping of them such as `Experiment.recipes`) with the setting at `path` parsed
    from `text`; `key` is the whole dotted key."""
    name, rest = path[0], path[1:]
    done = key[: len(key) - len(".".join(path))].rstrip(".")  # the part of the key already walked
    if isinstance(node, Mapping):
        return _set_entry(node, name, rest, text, key, done)
    if not dataclasses.is_dataclass(node):
        raise ConfigError(f"unknown key {key!r}: {done} is a value, not a group of settings")
    hints = typing.get_type_hints(type(node))
    fields = [field.name for field in dataclasses.fields(node) if field.init]
    if name not in fields:
        raise ConfigError(
            f"unknown key {key!r}: valid keys {'under ' + repr(done) if done else 'at the top level'} are "
            + ", ".join(f"{n}.*" if _is_group_value(getattr(node, n)) else n for n in fields)
        )
    current = getattr(node, name)
    record: Any = node  # a dataclass instance (checked above)
    if rest:
        return dataclasses.replace(record, **{name: _set(current, rest, text, key)})
    if _is_group_value(current):
        raise _group_named(key, current)
    bounds = next(field.metadata.get(serial.BOUNDS) for field in dataclasses.fields(node) if field.name == name)
    try:
        return dataclasses.replace(record, **{name: within(parse_value(text, hints[name]), bounds)})
    except ValueError as error:
        raise ConfigError(f"--set {key}={text}: {error}") from None


def _set_entry(node: Mapping, name: str, rest: list[str], text: str, key: str, done: str) -> dict:
    """The mapping `node` with the setting under its entry `name` changed (an entry is a group, never one value)."""
    if name not in node:
        raise ConfigError(f"unknown key {key!r}: valid keys under {done!r} are " + ", ".join(f"{n}.*" for n in node))
    if not rest:
        raise _group_named(key, node[name])
    return {**node, name: _set(node[name], rest, text, key)}


def _group_named(key: str, group) -> ConfigError:
    """The refusal of a `--set` key that names a group (a dataclass or a mapping), listing the keys inside it."""
    if isinstance(group, Mapping):
        inside = [f"{entry}.*" for entry in group]
    else:
        inside = [field.name for field in dataclasses.fields(group) if field.init]
    keys = ", ".join(f"{key}.{name}" for name in inside)
    return ConfigError(f"key {key!r} names a group of settings; set one of its keys: {keys}")


def _is_group_value(value) -> bool:
    return dataclasses.is_dataclass(value) or isinstance(value, Mapping)


def _unwrap_optional(hint) -> tuple[bool, object]:
    """(whether `hint` admits None, `hint` without None)."""
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        rest = [arg for arg in typing.get_args(hint) if arg is not type(None)]
        if len(rest) == 1:
            return len(rest) < len(typing.get_args(hint)), rest[0]
    return False, hint


def _is_group(hint) -> bool:
    inner = _unwrap_optional(hint)[1]
    return dataclasses.is_dataclass(inner) or typing.get_origin(inner) in (dict, Mapping)


class DeprecatedAlias(argparse.Action):
    """An old flag kept for one release: it stores into the new flag's `dest` and says what to use instead."""

    def __init__(self, option_strings, dest, instead: str, **kwargs):
        super().__init__(option_strings, dest, help=argparse.SUPPRESS, **kwargs)
        self.instead = instead

    def __call__(self, parser, namespace, values, option_string=None):
        if values is None:  # an optional positional left out: argparse still calls its action
            return
        print(
            f"{parser.prog}: {option_string or 'a positional folder'} is deprecated and goes in the next release; "
            f"use {self.instead}",
            file=sys.stderr,
        )
        setattr(namespace, self.dest, values)


def add_dataset_argument(parser: argparse.ArgumentParser, help_text: str, required: bool = False) -> None:
    """`--dataset DIR`, the one flag naming a dataset folder; the older `--data` and positional folder
    still work for one release, with a deprecation message."""
    parser.add_argument("--dataset", type=Path, help=help_text)
    parser.add_argument("--data", dest="dataset", type=Path, action=DeprecatedAlias, instead="--dataset DIR")
    if required:
        parser.add_argument("legacy_dataset", nargs="?", type=Path, action=DeprecatedAlias, instead="--dataset DIR")


def dataset_of(args: argparse.Namespace) -> Path:
    """The dataset folder of a command that needs one: `--dataset`, or the deprecated positional folder."""
    dataset = getattr(args, "dataset", None) or getattr(args, "legacy_dataset", None)
    if dataset is None:
        raise ConfigError("name the dataset folder with --dataset DIR")
    return dataset


def count(minimum: int = 0, maximum: int | None = None, none_below: int | None = None):
    """An argparse type: an integer in [`minimum`, `maximum`] (`none_below`: one more allowed value below,
    e.g. -1 for "all"), or argparse's usage error naming the range."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
        if value == none_below or (value >= minimum and (maximum is None or value <= maximum)):
            return value
        span = f"at least {minimum}" if maximum is None else f"from {minimum} to {maximum:,}"
        extra = f" (or {none_below})" if none_below is not None else ""
        raise argparse.ArgumentTypeError(f"{value} is out of range: give a whole number {span}{extra}")

    return parse


# Bounds of the CLI's numeric flags, each checked as the flag is read (before any work; issue 60).
MAX_WORKERS = 4096
MAX_SCENES = 99_999  # scene ids hold five digits
MAX_CHUNK = 4096


def number(least: float, most: float):
    """An argparse type: a finite number in [`least`, `most`], or argparse's usage error naming the range."""

    def parse(text: str) -> float:
        value = finite(text)
        if least <= value <= most:
            return value
        raise argparse.ArgumentTypeError(f"{value:g} is out of range: give a number from {least:g} to {most:g}")

    return parse


def finite(text: str) -> float:
    """An argparse type: a finite number."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text} is not a finite number")
    return value


# The longest any duration flag may ask for: past it a platform's timers overflow (1e9 s is 32 years), and no
# step of ocplace is meant to wait that long.
MAX_DURATION_S = 86_400.0


def seconds(text: str) -> float:
    """An argparse type: a finite, non-negative number of seconds, at most `MAX_DURATION_S` (one day)."""
    value = finite(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"{text} is negative: give seconds, 0 or more")
    if value > MAX_DURATION_S:
        raise argparse.ArgumentTypeError(f"{text} s is more than a day ({MAX_DURATION_S:g} s): give at most that")
    return value
