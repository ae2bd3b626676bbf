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
from collections.abc import Mapping
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
    hints = _hints(cls)
    unknown = set(fields) - set(hints)
    if unknown:
        raise TypeError(f"{cls.__name__} has no field {', '.join(sorted(unknown))}")
    readers = _readers(cls)
    return cls(
        **{
            name: readers[name](value) if name in readers else _from(value, hints[name])
            for name, value in fields.items()
        }
    )


def from_json(cls: type[T], text: str) -> T:
    return from_dict(cls, json.loads(text))


@functools.cache
def _hints(cls: type) -> dict:
    return typing.get_type_hints(cls)


@functools.cache
def _readers(cls: type) -> dict:
    return {field.name: field.metadata[READ] for field in dataclasses.fields(cls) if READ in field.metadata}


def _from(value, hint):
    if value is None:
        return None
    origin, arguments = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        return _from(value, next(a for a in arguments if a is not type(None)))
    if dataclasses.is_dataclass(hint):
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
