"""Reads PyTorch's legacy (non-zip, before 1.6) `torch.save` files with pickle and NumPy, no torch.

The legacy layout is a run of pickles followed by raw storage bytes:
    magic number, protocol version, sys_info      three small pickles
    the saved object                              tensors refer to storages by persistent id
                                                  ('storage', type, key, location, numel[, view])
    the list of storage keys                      in the order their bytes follow
    for each storage: int64 element count, then count * itemsize raw little-endian bytes

Pickles can run arbitrary code, so every pickle is read by `_RestrictedUnpickler`, which resolves
only the few globals a state dict needs and refuses all others before anything is called.
"""

from __future__ import annotations

import collections
import dataclasses
import os
import pickle
import struct
from typing import Any, BinaryIO

import numpy as np

from ocplace.errors import WeightsError

MAGIC_NUMBER = 0x1950A86A20F9469CFC6C
PROTOCOL_VERSION = 1001

# Storage classes of the legacy format and the NumPy dtype of their elements (little-endian).
STORAGE_DTYPES: dict[str, np.dtype] = {
    "DoubleStorage": np.dtype("<f8"),
    "FloatStorage": np.dtype("<f4"),
    "HalfStorage": np.dtype("<f2"),
    "LongStorage": np.dtype("<i8"),
    "IntStorage": np.dtype("<i4"),
    "ShortStorage": np.dtype("<i2"),
    "CharStorage": np.dtype("i1"),
    "ByteStorage": np.dtype("u1"),
    "BoolStorage": np.dtype("?"),
}


@dataclasses.dataclass(frozen=True)
class _StorageType:
    dtype: np.dtype


@dataclasses.dataclass
class _Storage:
    """A storage named by the main pickle; `data` is filled in once the raw bytes are read."""

    key: str
    dtype: np.dtype
    numel: int
    data: np.ndarray | None = None


@dataclasses.dataclass(frozen=True)
class _TensorRef:
    """A tensor as `_rebuild_tensor_v2` describes it: a strided view of a storage."""

    storage: _Storage
    offset: int
    shape: tuple[int, ...]
    stride: tuple[int, ...]


def _rebuild_tensor(storage, storage_offset, size, stride, *_ignored) -> _TensorRef:
    """Stands in for `torch._utils._rebuild_tensor(_v2)`; `_ignored` is requires_grad, hooks, metadata."""
    if not isinstance(storage, _Storage):
        raise WeightsError("a tensor in the weight file does not refer to a storage; the file is corrupt")
    return _TensorRef(storage, int(storage_offset), tuple(int(s) for s in size), tuple(int(s) for s in stride))


def _rebuild_parameter(data, requires_grad=False, backward_hooks=None, *_ignored):
    """Stands in for `torch._utils._rebuild_parameter`: a parameter is its tensor."""
    return data


_SAFE_GLOBALS: dict[tuple[str, str], Any] = {
    ("collections", "OrderedDict"): collections.OrderedDict,
    ("torch._utils", "_rebuild_tensor"): _rebuild_tensor,
    ("torch._utils", "_rebuild_tensor_v2"): _rebuild_tensor,
    ("torch._utils", "_rebuild_parameter"): _rebuild_parameter,
    **{("torch", name): _StorageType(dtype) for name, dtype in STORAGE_DTYPES.items()},
}


class _RestrictedUnpickler(pickle.Unpickler):
    """Resolves only `_SAFE_GLOBALS`; storages come back as `_Storage` placeholders."""

    def __init__(self, file: BinaryIO, storages: dict[str, _Storage]):
        super().__init__(file)
        self.storages = storages

    def find_class(self, module: str, name: str):
        try:
            return _SAFE_GLOBALS[(module, name)]
        except KeyError:
            raise WeightsError(
                f"the weight file asks to load {module}.{name}, which a tensor state dict never needs; "
                "refusing to unpickle it (it could run code). Use a weight file from a trusted source"
            ) from None

    def persistent_load(self, pid):
        if not (isinstance(pid, tuple) and len(pid) in (5, 6) and pid[0] == "storage"):
            raise WeightsError(f"unexpected persistent id {pid!r}: not a legacy torch.save file")
        _, storage_type, key, _location, numel = pid[:5]
        if len(pid) == 6 and pid[5] is not None:
            raise WeightsError("the weight file uses storage views (torch < 0.4); re-save it with a newer torch")
        if not isinstance(storage_type, _StorageType):
            raise WeightsError(f"unsupported storage type {storage_type!r} in the weight file")
        storage = self.storages.setdefault(key, _Storage(str(key), storage_type.dtype, int(numel)))
        return storage


def _unpickle(file: BinaryIO, storages: dict[str, _Storage]) -> Any:
    try:
        return _RestrictedUnpickler(file, storages).load()
    except WeightsError:
        raise
    except Exception as error:  # a truncated or garbled pickle raises many different types
        raise WeightsError(f"the weight file is not a readable legacy torch.save file ({error})") from error


def read_legacy(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """A legacy `torch.save` state dict as `{name: array}`, arrays in the storages' dtypes."""
    with open(path, "rb") as file:
        return load_legacy(file)


def load_legacy(file: BinaryIO) -> dict[str, np.ndarray]:
    """As `read_legacy`, from an open, seekable binary file positioned at its start."""
    start = file.tell()
    if file.read(4) == b"PK\x03\x04":
        raise WeightsError(
            "the weight file is a zip archive (torch.save of torch >= 1.6), not the legacy format "
            "this reader handles; re-save it with `torch.save(..., _use_new_zipfile_serialization=False)`"
        )
    file.seek(start)
    storages: dict[str, _Storage] = {}
    _check_header(file, storages)
    state = _unpickle(file, storages)
    keys = _unpickle(file, storages)
    if not isinstance(keys, list):
        raise WeightsError("the weight file's storage key list is missing; the file is corrupt")
    for key in keys:
        _read_storage(file, storages, key)
    return _materialise(state, path_hint=getattr(file, "name", "the weight file"))


def _check_header(file: BinaryIO, storages: dict[str, _Storage]) -> None:
    magic = _unpickle(file, storages)
    if magic != MAGIC_NUMBER:
        raise WeightsError(
            "not a legacy torch.save file (wrong magic number); files saved by torch >= 1.6 "
            "are zip archives, which this reader does not handle"
        )
    version = _unpickle(file, storages)
    if version != PROTOCOL_VERSION:
        raise WeightsError(f"unsupported torch.save protocol version {version!r} (expected {PROTOCOL_VERSION})")
    sys_info = _unpickle(file, storages)
    if isinstance(sys_info, dict) and not sys_info.get("little_endian", True):
        raise WeightsError("the weight file was saved on a big-endian machine; re-save it on a little-endian one")


def _read_storage(file: BinaryIO, storages: dict[str, _Storage], key) -> None:
    storage = storages.get(key)
    if storage is None:
        raise WeightsError(f"the weight file lists storage {key!r}, which no tensor uses; the file is corrupt")
    (count,) = struct.unpack("<q", _read_exactly(file, 8))
    if count != storage.numel:
        raise WeightsError(f"storage {key!r} holds {count} elements, the tensors expect {storage.numel}")
    raw = _read_exactly(file, count * storage.dtype.itemsize)
    storage.data = np.frombuffer(raw, storage.dtype)


def _read_exactly(file: BinaryIO, size: int) -> bytes:
    data = file.read(size)
    if len(data) != size:
        raise WeightsError("the weight file ends early; it is truncated, download or reinstall it")
    return data


def _materialise(state, path_hint: str) -> dict[str, np.ndarray]:
    if not isinstance(state, dict):
        raise WeightsError(f"{path_hint} holds a {type(state).__name__}, not a state dict of tensors")
    arrays = {}
    for name, value in state.items():
        if not isinstance(value, _TensorRef):
            raise WeightsError(f"entry {name!r} of {path_hint} is not a tensor")
        arrays[str(name)] = _tensor_array(name, value)
    return arrays


def _tensor_array(name: str, ref: _TensorRef) -> np.ndarray:
    """A contiguous copy of the strided view, after checking it stays inside its storage."""
    data = ref.storage.data
    if data is None:
        raise WeightsError(f"tensor {name!r} refers to storage {ref.storage.key!r}, whose bytes are missing")
    if any(s < 0 for s in ref.shape) or any(s < 0 for s in ref.stride) or ref.offset < 0:
        raise WeightsError(f"tensor {name!r} has a negative size, stride or offset")
    if 0 in ref.shape:
        return np.zeros(ref.shape, data.dtype)
    last = ref.offset + sum((n - 1) * s for n, s in zip(ref.shape, ref.stride))
    if last >= data.size:
        raise WeightsError(f"tensor {name!r} reaches past the end of its storage; the file is corrupt")
    view = np.lib.stride_tricks.as_strided(
        data[ref.offset :], ref.shape, tuple(s * data.itemsize for s in ref.stride), writeable=False
    )
    return np.ascontiguousarray(view).astype(data.dtype.newbyteorder("="), copy=False)
