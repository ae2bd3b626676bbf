"""What a dataset split is, by content: its files, their hash, and the feature file they key.

Caches built from a split (features, sentence tokens, baseline inputs) are named and keyed by
`dataset_hash`, which covers that split's files only: other splits may change without effect.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

from ocplace.errors import FeaturesError
from ocplace.paths import features_cache


def split_files(dataset_dir: Path, split: str) -> list[tuple[str, str]]:
    """Sorted `(relative path, sha256)` of the split's files, from the dataset manifest."""
    from ocplace.sim.dataset.config import generate_advice
    from ocplace.sim.dataset.job import read_manifest

    files = read_manifest(dataset_dir)["files"]
    chosen = sorted((name, digest) for name, digest in files.items() if name.startswith(f"{split}/"))
    if not chosen:
        raise FeaturesError(f"{dataset_dir} has no scenes in split {split!r}; {generate_advice(dataset_dir, split)}")
    return chosen


def dataset_hash(dataset_dir: Path, split: str) -> str:
    """sha256 over the manifest's file hashes of `split`: other splits may change without effect."""
    return hashlib.sha256(json.dumps(split_files(dataset_dir, split)).encode()).hexdigest()


def split_features_path(dataset_dir: Path, split: str, backbone_fingerprint: str) -> Path:
    """Where `ocplace featurize` caches a split's features, so every user of them shares one file."""
    digest = dataset_hash(dataset_dir, split)
    return features_cache() / f"{digest[:16]}-{split}-{backbone_fingerprint[:16]}.safetensors"
