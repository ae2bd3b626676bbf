"""One serialiser for every config and record dataclass: JSON types out, the same dataclass back by its type hints.

`to_dict` writes a frozen dataclass tree as JSON types (tuples as lists, paths as strings, NumPy values
as numbers or lists); `to_json` is its canonical text (sorted keys), which caches and run files hash;
`from_dict` rebuilds the dataclass from the hints of its fields (nested dataclasses, `tuple[X, ...]`,
`tuple[X, Y]`, `X | None`, `Path`). A class that leaves fields out of its text, so that a key
changes only with what matters, names them in a `serial_omitted()` method; a field whose hint cannot say
what to rebuild (a mapping whose values' types a registry knows) names its reader in its metadata (`READ`).
"""

from __future__ import annotations

import dataclasses
import functools
import json
import types
import typing
from collections.abc import Hashable, Mapping
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

T = TypeVar("T")
READ = "serial_read"  # a field's metadata key: the function rebuilding its value from its JSON types


def to_dict(value: object) -> Any:
    """`value` as JSON types; a dataclass as a dict of its fields (less its `serial_omitted()` ones); what JSON
    has no type for (a path, ...) as its `str`."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        omitted = value.serial_omitted() if hasattr(value, "serial_omitted") else ()
        return {f.name: to_dict(getattr(value, f.name)) for f in dataclasses.fields(value) if f.name not in omitted}
    if isinstance(value, dict):
        return {str(key): to_dict(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [to_dict(item) for item in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    return str(value)  # a path, or anything else a method describes itself with


def to_json(value: object) -> str:
    """The canonical text of `to_dict(value)`: sorted keys, JSON's default separators."""
    return json.dumps(to_dict(value), sort_keys=True)


def from_dict(cls: type[T], fields: Mapping[str, Any]) -> T:
    """The `cls` dataclass of `to_dict`'s output (or of JSON text read back); fields it lacks keep their defaults.
    A field `cls` does not have is a TypeError, as in `cls(**fields)`: such text was written by something else."""
    hints = _hints(typing.cast(Hashable, cls))  # a class is hashable; typeshed's `type[T]` does not say so
    unknown = set(fields) - set(hints)
    if unknown:
        raise TypeError(f"{cls.__name__} has no field {', '.join(sorted(unknown))}")
    readers = _readers(typing.cast(Hashable, cls))
    return cls(
        **{
            name: readers[name](value) if name in readers else _from(value, hints[name])
            for name, value in fields.items()
        }
    )


def from_json(cls: type[T], text: str) -> T:
    return from_dict(cls, json.loads(text))


@functools.cache
def _hints(cls: Hashable) -> dict[str, Any]:
    return typing.get_type_hints(cls)


@functools.cache
def _readers(cls: Hashable) -> dict[str, Any]:
    return {field.name: field.metadata[READ] for field in dataclasses.fields(cls) if READ in field.metadata}  # type: ignore[arg-type]  # a dataclass's class, hashable


def _from(value, hint):
    if value is None:
        return None
    origin, arguments = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        return _from(value, next(a for a in arguments if a is not type(None)))
    if isinstance(hint, type) and dataclasses.is_dataclass(hint):
        return from_dict(hint, value)
    if origin is tuple:
        if len(arguments) == 2 and arguments[1] is Ellipsis:
            return tuple(_from(item, arguments[0]) for item in value)
        return tuple(_from(item, inner) for item, inner in zip(value, arguments or [typing.Any] * len(value)))
    if hint is tuple:
        return tuple(value)
    if hint is Path:
        return Path(value)
    return value


# ----------------------------------------------------------------------------- checking text before rebuilding it

BOUNDS = "bounds"  # a field's metadata key: `(least, most)` for a number, or for each number of a tuple of them
MAX_TEXT = 1_000  # characters of any text field
MAX_ITEMS = 64  # items of any `tuple[X, ...]` field


def bounded(default: Any, least: float, most: float, **metadata: Any) -> Any:
    """A dataclass field whose value (or each number of its tuple) must lie in `[least, most]` in text read back."""
    return dataclasses.field(default=default, metadata={BOUNDS: (least, most), **metadata})


def text_problems(cls: type, data: object, where: str) -> list[str]:
    """Every way `data` (decoded JSON) is not text `from_dict(cls, ...)` may rebuild: an unknown field, a value of
    the wrong type, not finite, or outside its field's `bounds`; a field `data` lacks keeps its default. Then the
    rebuilt value's own `problems()`, when it has them and the fields are sound. One message per problem, each
    naming its field by path (`where.field.sub`)."""
    if not isinstance(data, Mapping):
        return [f"{where}: an object of {cls.__name__}'s fields is needed, got {_kind(data)}"]
    hints, fields = _hints(cls), {field.name: field for field in dataclasses.fields(cls)}
    found = [f"{where}.{name}: not a field of {cls.__name__}" for name in sorted(set(data) - set(fields), key=str)]
    for name, value in data.items():
        if name in fields:
            found += _value_problems(value, hints[name], fields[name].metadata.get(BOUNDS), f"{where}.{name}")
    if not found and hasattr(cls, "problems"):
        try:
            rebuilt: Any = from_dict(cls, data)
            found += [f"{where}: {problem}" for problem in rebuilt.problems()]
        except (TypeError, ValueError) as error:
            found.append(f"{where}: {error}")
    return found


def _kind(value: object) -> str:
    return "null" if value is None else f"{type(value).__name__} {_short(value)}"


def _short(value: object) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _value_problems(value, hint, bounds, where: str) -> list[str]:
    origin, arguments = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in arguments:
            return []
        return _value_problems(value, next(a for a in arguments if a is not type(None)), bounds, where)
    if isinstance(hint, type) and dataclasses.is_dataclass(hint):
        return text_problems(hint, value, where)
    if origin is typing.Literal:
        return [] if value in arguments else [f"{where}: one of {', '.join(map(repr, arguments))}, got {_kind(value)}"]
    if origin is tuple or hint is tuple:
        return _tuple_problems(value, arguments, bounds, where)
    if hint is bool:
        return [] if isinstance(value, bool) else [f"{where}: true or false, got {_kind(value)}"]
    if hint in (int, float):
        return _number_problems(value, hint, bounds, where)
    if hint in (str, Path):
        if isinstance(value, str) and len(value) <= MAX_TEXT:
            return []
        return [f"{where}: a text of at most {MAX_TEXT:,} characters, got {_kind(value)}"]
    return []


def _number_problems(value, hint, bounds, where: str) -> list[str]:
    import math

    whole = hint is int
    if isinstance(value, bool) or not isinstance(value, int if whole else (int, float)):
        return [f"{where}: {'an integer' if whole else 'a number'}, got {_kind(value)}"]
    if not math.isfinite(value):
        return [f"{where}: a finite number, got {value}"]
    if bounds is not None and not bounds[0] <= value <= bounds[1]:
        return [f"{where}: from {_number(bounds[0])} to {_number(bounds[1])}, got {_number(value)}"]
    return []


def _number(value: float) -> str:
    return f"{value:,}" if isinstance(value, int) else f"{value:g}"


def _tuple_problems(value, arguments, bounds, where: str) -> list[str]:
    if not isinstance(value, list | tuple) or len(value) > MAX_ITEMS:
        return [f"{where}: a list of at most {MAX_ITEMS} items, got {_kind(value)}"]
    if len(arguments) == 2 and arguments[1] is Ellipsis:
        inner = [arguments[0]] * len(value)
    elif arguments and len(arguments) != len(value):
        return [f"{where}: a list of {len(arguments)} items, got {len(value)}"]
    else:
        inner = list(arguments) or [typing.Any] * len(value)
    found = []
    for index, (item, hint) in enumerate(zip(value, inner, strict=True)):
        found += _value_problems(item, hint, bounds, f"{where}[{index}]")
    return found
