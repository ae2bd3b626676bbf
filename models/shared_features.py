"""Test-scene features shared by every evaluation on one backbone, encoded once and read by the rest.

Ours, Ours w/o Adapter and Ours w/o LLM score the same test scenes with the same frozen backbone, so
each would encode the same crops, workspace images and phrases again. `SharedFeatures` is that
backbone with a store: every batch it encodes is written once under the backbone's fingerprint,
keyed by the batch's exact bytes, and every later request for that batch (another method, another
seed, a rerun) reads it back.

Why keyed by the batch, not by scene: the policy encodes its scenes in chunks, and a jitted network
on XLA's CPU may split its reductions differently for another batch size, so a scene's features
encoded in another batch could differ in the last bits from the ones the method would compute
itself (measured: the demo backbone's features of 3 crops encoded alone and in a batch of 40 differ
by up to 3e-8). Ours and w/o Adapter parse and chunk their scenes alike, so they ask for the same batches
(and w/o LLM too where every instruction parses): the same batch gives the same bits by construction,
and a batch no one encoded before is simply encoded.

Files (`$OCPLACE_CACHE/features/shared/<fingerprint[:16]>/<kind>-<digest>.safetensors`, one array
`features` with the fingerprint, the input's digest and a content hash in their metadata:
`models.weights_file`) are written atomically under a lock (`ocplace.paths.file_lock`), so two tasks
asking for a batch at once encode it once; a file that does not verify (damaged content, another
fingerprint or input, a wrong shape, not readable) is encoded again and replaced. A store that cannot be
written (a full or read-only disk) is one warning, and the features are used from memory.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from ocplace.errors import CacheError, OutputError, WeightsError
from ocplace.models.backbone import Backbone
from ocplace.models.weights_file import load_weights, save_weights
from ocplace.paths import features_cache, file_lock

log = logging.getLogger(__name__)

FORMAT = "ocplace-shared-features-2"  # 2: with a content hash (`models.weights_file`); 1 is encoded again


def shared_folder(fingerprint: str) -> Path:
    return features_cache() / "shared" / fingerprint[:16]


class SharedFeatures:
    """A `Backbone` that reads each batch it is asked to encode from the store when it is there."""

    def __init__(self, backbone: Backbone, folder: Path | None = None):
        self.backbone = backbone
        self.folder = folder or shared_folder(backbone.fingerprint)
        self._warned = False

    @property
    def dim(self) -> int:
        return self.backbone.dim

    @property
    def fingerprint(self) -> str:
        return self.backbone.fingerprint

    @property
    def logit_scale(self) -> float:
        return self.backbone.logit_scale

    def encode_images(self, images: np.ndarray) -> np.ndarray:
        images = np.ascontiguousarray(images)
        described = f"{images.dtype.str}{images.shape}".encode()
        return self._stored("images", described + images.tobytes(), len(images), self.backbone.encode_images, images)

    def encode_texts(self, texts: Sequence[str]) -> np.ndarray:
        texts = list(texts)
        return self._stored("texts", json.dumps(texts).encode(), len(texts), self.backbone.encode_texts, texts)

    def _stored(self, kind: str, data: bytes, rows: int, encode: Callable, batch) -> np.ndarray:
        digest = hashlib.sha256(data).hexdigest()
        path = self.folder / f"{kind}-{digest[:32]}.safetensors"
        found = self._read(path, digest, rows)
        if found is not None:
            return found
        with contextlib.ExitStack() as stack:
            try:  # another task may be encoding this batch: wait, then read what it wrote
                stack.enter_context(file_lock(path))
            except (OSError, CacheError) as error:
                self._cannot_write(error)
                return np.asarray(encode(batch), np.float32)
            found = self._read(path, digest, rows)
            if found is not None:
                return found
            features = np.asarray(encode(batch), np.float32)
            try:
                save_weights(path, {"features": features}, self._metadata(digest))
            except (OSError, OutputError) as error:
                self._cannot_write(error)
            return features

    def _metadata(self, digest: str) -> dict[str, str]:
        return {"format": FORMAT, "fingerprint": self.fingerprint, "input": digest}

    def _cannot_write(self, error: Exception) -> None:
        """A store that cannot be written is no reason to fail a scene: warn once, go on in memory."""
        if not self._warned:
            self._warned = True
            log.warning("cannot write the shared test features in %s (%s): encoding in memory", self.folder, error)

    def _read(self, path: Path, digest: str, rows: int) -> np.ndarray | None:
        if not path.is_file():
            return None
        try:
            tensors, meta = load_weights(path, "it is encoded again")
        except (WeightsError, OSError) as error:
            log.warning("%s does not verify (%s): encoding its batch again", path, error)
            return None
        features = tensors.get("features")
        if meta != self._metadata(digest) or features is None or features.shape != (rows, self.dim):
            log.warning("%s does not match its batch or backbone: encoding the batch again", path)
            return None
        return features
