"""Weight files that vouch for their content: safetensors with a content hash, checked on load.

`save_weights` writes the tensors atomically with `HASH_KEY` in the safetensors metadata: the
sha256 of the other metadata (sorted JSON) and of every tensor's name, dtype, shape and bytes, in
name order. The hash travels inside the file it covers, so the rename that publishes the tensors
publishes their hash with them. `load_weights` refuses, with a `WeightsError` that names the file
and says how to rebuild it: a file safetensors cannot parse (truncated, damaged header), content
that does not hash to the stored value (flipped bits), and NaN or inf in a floating-point tensor
(a diverged run, or damage in a file too old to carry a hash). Files without a hash, written
before it existed, load with a warning. See docs/reliability.md#weights.
"""

from __future__ import annotations

import hashlib
import json
import logging
from pathlib import Path

import jax
import numpy as np

from ocplace.errors import FileRefused, TrainingError, WeightsError
from ocplace.paths import MAX_WEIGHTS_BYTES, regular_file, write_bytes_atomic

log = logging.getLogger(__name__)

HASH_KEY = "ocplace_content_sha256"


def content_sha256(tensors: dict[str, np.ndarray], metadata: dict[str, str]) -> str:
    """Independent of the file layout: safetensors orders its header as it likes."""
    digest = hashlib.sha256(json.dumps(metadata, sort_keys=True).encode())
    for name in sorted(tensors):
        array = np.asarray(tensors[name], order="C")
        digest.update(json.dumps([name, array.dtype.str, array.shape]).encode())
        digest.update(array.tobytes())
    return digest.hexdigest()


def flatten_state(state) -> dict[str, np.ndarray]:
    """Every leaf of a pytree (params, optimiser state) under its key path, as a numpy array."""
    return {jax.tree_util.keystr(path): np.array(leaf) for path, leaf in jax.tree_util.tree_leaves_with_path(state)}


def unflatten_state(arrays: dict[str, np.ndarray], template):
    """`template`'s structure filled with `arrays`; keys, shapes and dtypes must match exactly."""
    paths, treedef = jax.tree_util.tree_flatten_with_path(template)
    expected = {jax.tree_util.keystr(path): leaf for path, leaf in paths}
    mismatched = sorted(set(arrays) ^ set(expected)) + sorted(
        key
        for key, leaf in expected.items()
        if key in arrays and (arrays[key].shape != tuple(leaf.shape) or arrays[key].dtype != np.dtype(leaf.dtype))
    )
    if mismatched:
        raise TrainingError(
            f"checkpoint does not match the model ({', '.join(mismatched[:3])} ...); start a new "
            "run directory (--out) for a different configuration"
        )
    return jax.tree_util.tree_unflatten(treedef, [arrays[jax.tree_util.keystr(path)] for path, _ in paths])


def save_weights(path: str | Path, tensors: dict[str, np.ndarray], metadata: dict[str, str]) -> Path:
    """Writes `tensors` and `metadata` (str to str) to `path` atomically, with their content hash."""
    from safetensors.numpy import save

    tensors = {name: np.asarray(array, order="C") for name, array in tensors.items()}
    blob = save(tensors, metadata={**metadata, HASH_KEY: content_sha256(tensors, metadata)})
    write_bytes_atomic(path, _sorted_header(blob))
    return Path(path)


def _sorted_header(blob: bytes) -> bytes:
    """safetensors writes the metadata in hash-map order, which changes from call to call; with the
    header's keys sorted, the same weights give the same bytes (runs compare and report file hashes)."""
    size = int.from_bytes(blob[:8], "little")
    header = json.dumps(json.loads(blob[8 : 8 + size]), sort_keys=True, separators=(",", ":")).encode()
    header += b" " * (-len(header) % 8)  # safetensors keeps the tensor data 8-byte aligned
    return len(header).to_bytes(8, "little") + header + blob[8 + size :]


def load_weights(path: str | Path, rebuild: str) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """`(tensors, metadata)` of a file `save_weights` wrote, verified; `rebuild` tells the user how to remake it."""
    tensors, metadata = _read(path, rebuild)
    stored = metadata.pop(HASH_KEY, None)
    if stored is None:
        log.warning(
            "%s has no content hash (written by an older ocplace), so damage cannot be detected; "
            "loading it anyway. To protect it, %s",
            path,
            rebuild,
        )
    elif stored != content_sha256(tensors, metadata):
        raise WeightsError(f"{path} does not match its content hash: the file is damaged or was edited; {rebuild}")
    _check_finite(path, tensors, rebuild)
    return tensors, metadata


def read_weights(path: str | Path, rebuild: str) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """`load_weights` without the hash, for files whose loader checks a hash of its own (the offline backbone)."""
    tensors, metadata = _read(path, rebuild)
    _check_finite(path, tensors, rebuild)
    return tensors, metadata


def _read(path: str | Path, rebuild: str) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    from safetensors import SafetensorError, safe_open

    try:
        regular_file(path, MAX_WEIGHTS_BYTES)  # a FIFO would block the read, a device never end it
    except FileRefused as error:
        raise WeightsError(f"{error}; {rebuild}") from None
    except FileNotFoundError:
        pass  # safe_open says so, as before
    try:
        with safe_open(str(path), framework="numpy") as handle:
            metadata = dict(handle.metadata() or {})
            tensors = {name: handle.get_tensor(name) for name in handle.keys()}
    except (SafetensorError, OSError) as error:
        raise WeightsError(f"{path} cannot be read ({error}): it is truncated or damaged; {rebuild}") from error
    return tensors, metadata


def _check_finite(path: str | Path, tensors: dict[str, np.ndarray], rebuild: str) -> None:
    for name in sorted(tensors):
        array = tensors[name]
        if np.issubdtype(array.dtype, np.floating) and not np.isfinite(array).all():
            raise WeightsError(
                f"{path} holds NaN or inf weights ({name}): the run diverged or the file is damaged; "
                f"{rebuild} (a run that diverges again needs a lower learning rate)"
            )


# The metadata key each kind of weights file carries, and the words a message names that kind by: a loader given
# another kind (`evaluate --run ours=RUN` where RUN is a w/o LLM run) names both (issue 60, item 8).
WEIGHTS_KINDS = {
    "adapter_config": "Ours' CLIP-Adapters (a run of Ours or of a row trained as Ours is)",
    "model_config": "the model of a w/o LLM run (no_llm)",
    "run": "the weights of a {method} run",
    "format": "a policy folder's model (`ocplace export`)",
}


def weights_kind(metadata: dict[str, str]) -> str:
    """What a weights file holds, in words, by the metadata its writer put in it."""
    for key, words in WEIGHTS_KINDS.items():
        if key in metadata:
            try:
                method = json.loads(metadata[key]).get("method", "baseline") if key == "run" else ""
            except (ValueError, AttributeError):
                method = "baseline"
            return words.format(method=method)
    return "weights no ocplace row writes"


def expect_kind(path: str | Path, metadata: dict[str, str], needed: list[str], wanted: str, example: str) -> None:
    """TrainingError naming what `path` holds and the `wanted` kind, unless its metadata has the `needed` fields;
    `example` is a path of the wanted kind."""
    missing = [field for field in needed if field not in metadata]
    if missing:
        raise TrainingError(
            f"{path} holds {weights_kind(metadata)}, not {wanted} (its metadata lacks {', '.join(missing)}); "
            f"pass a run of the row you meant (e.g. `{example}`)"
        )
