"""The built object library, read from the cache."""

from __future__ import annotations

import dataclasses
import difflib
import hashlib
import json
import types
from collections.abc import Mapping
from pathlib import Path

from ocplace.errors import LibraryNotBuilt, UnknownObject
from ocplace.paths import file_sha256, inside, library_cache
from ocplace.sim.colour_terms import COLOUR_TERMS
from ocplace.sim.library.checksums import read_checked
from ocplace.sim.library.metadata import packaged_objects
from ocplace.sim.library.records import (
    MANIFEST_FILE,
    asset_from_json,
    manifest_problem,
)
from ocplace.sim.library.types import ObjectAsset
from ocplace.vocabulary import LIBRARY_SPLITS

BUILD_HINT = "run `ocplace assets build`"


@dataclasses.dataclass(frozen=True)
class TableTexture:
    name: str
    path: Path  # PNG, <= 1024 px
    split: str  # "seen" or "unseen" (table textures have no unseen_cat split)


@dataclasses.dataclass(frozen=True)
class Library:
    """Read-only view of a built library: only objects whose build succeeded."""

    objects: Mapping[str, ObjectAsset]
    textures: Mapping[str, TableTexture]
    root: Path
    manifest: Mapping  # the manifest as written, failed objects included

    def __reduce__(self):
        # Read-only views do not pickle; a worker process (the parallel pretraining render) gets the same library.
        return (_read_only, (dict(self.objects), dict(self.textures), self.root, dict(self.manifest)))

    def get(self, name: str) -> ObjectAsset:
        """By name ("alphabet_soup") or human name ("alphabet soup can"), case-insensitive."""
        key = name.strip().lower()
        if key in self.objects:
            return self.objects[key]
        for asset in self.objects.values():
            if asset.human_name.lower() == key:
                return asset
        candidates = list(self.objects) + [a.human_name for a in self.objects.values()]
        close = difflib.get_close_matches(key, candidates, n=5, cutoff=0.5)
        hint = f"; close matches: {', '.join(close)}" if close else ""
        raise UnknownObject(f"no object {name!r} in the library{hint} (see `ocplace assets list`)")

    def names(self, split: str | None = None) -> list[str]:
        return sorted(n for n, a in self.objects.items() if split is None or a.split == split)

    def summary(self) -> str:
        """`"30 seen + 13 unseen + 10 unseen_cat objects, 6 table textures"`."""
        counts = " + ".join(f"{len(self.names(split))} {split}" for split in LIBRARY_SPLITS)
        return f"{counts} objects, {len(self.textures)} table textures"


def colour_variants(library: Library) -> list[str]:
    """The seen objects that are another colour of an earlier seen object: the rule of the `seen_colour` pool.

    A seen object is a colour variant when its name or its human name, without a leading colour term, is that
    of a seen object of the same category listed before it in objects.json (green_ketchup after ketchup, "red
    bowl" after "white bowl", "red mug" after "white mug"). Written from the names alone, before any score.
    """
    order = {spec.name: index for index, spec in enumerate(packaged_objects())}
    seen = sorted(
        (asset for asset in library.objects.values() if asset.split == "seen"),
        key=lambda asset: (order.get(asset.name, len(order)), asset.name),  # objects added with --gso come last
    )
    variants = []
    for index, asset in enumerate(seen):
        keys = _uncoloured(asset)
        if any(earlier.category == asset.category and keys & _uncoloured(earlier) for earlier in seen[:index]):
            variants.append(asset.name)
    return sorted(variants)


def _uncoloured(asset: ObjectAsset) -> set[str]:
    """The asset's name and human name, each without a leading colour term (when it has one)."""
    keys = set()
    for words in (asset.name.split("_"), asset.human_name.lower().split()):
        if words[0] in COLOUR_TERMS and len(words) > 1:
            keys.add(" ".join(words[1:]))
        else:
            keys.add(" ".join(words))
    return keys


def _read_manifest(root: Path) -> dict:
    path = root / MANIFEST_FILE
    try:
        manifest = json.loads(path.read_text())
    except FileNotFoundError:
        raise LibraryNotBuilt(f"no object library in {root}; {BUILD_HINT}") from None
    except (OSError, ValueError) as error:
        raise LibraryNotBuilt(f"unreadable {path} ({error}); {BUILD_HINT}") from error
    problem = manifest_problem(manifest)
    if problem is not None:
        raise LibraryNotBuilt(f"{path} is not a library manifest this ocplace reads: {problem}; {BUILD_HINT}")
    return manifest


def _read_asset(root: Path, entry: dict) -> ObjectAsset:
    try:
        directory = inside(root, entry["folder"])
        return asset_from_json(read_checked(directory), directory)
    except (OSError, ValueError, KeyError) as error:
        raise LibraryNotBuilt(
            f"object {entry['name']!r} in {root} is incomplete or damaged ({error}); {BUILD_HINT}"
        ) from error


def load_library(cache: str | Path | None = None) -> Library:
    """Reads the library under `<cache>/library` (`ocplace.paths.library_cache`).

    Raises `LibraryNotBuilt` when the manifest or any object it lists as built is missing.
    """
    return load_library_at(library_cache(cache))


def load_library_at(root: Path) -> Library:
    """The library whose manifest is in `root`: the benchmark's, or a user catalogue's (`catalogue_library.py`)."""
    manifest = _read_manifest(root)
    objects = {entry["name"]: _read_asset(root, entry) for entry in manifest["objects"] if entry["status"] == "ok"}
    textures = {}
    for entry in manifest["textures"]:
        try:
            path = inside(root, entry["file"])
        except ValueError as error:
            raise LibraryNotBuilt(f"table texture {entry['name']!r} of {root}: {error}; {BUILD_HINT}") from None
        if not path.is_file():
            raise LibraryNotBuilt(f"table texture {path} is missing; {BUILD_HINT}")
        if entry.get("sha256") not in (None, file_sha256(path)):
            raise LibraryNotBuilt(f"table texture {path} changed since it was built; {BUILD_HINT}")
        textures[entry["name"]] = TableTexture(entry["name"], path, entry["split"])
    return _read_only(objects, textures, root, manifest)


def _read_only(objects: dict, textures: dict, root: Path, manifest: dict) -> Library:
    return Library(
        objects=types.MappingProxyType(objects),
        textures=types.MappingProxyType(textures),
        root=root,
        manifest=types.MappingProxyType(manifest),
    )


def added_objects_digest(cache: str | Path | None = None) -> str:
    """'' when the built library holds the packaged objects in their splits (the benchmark's pools); else 12 hex
    digits over what differs (objects added with `--gso`, by content key; packaged ones missing), so that a backbone
    pretrained on another pool is cached under another key. Reads the manifest only; no library: ''."""
    try:
        manifest = json.loads((library_cache(cache) / MANIFEST_FILE).read_text())
        entries = [e for e in manifest["objects"] if e["status"] == "ok"]
    except (OSError, ValueError, KeyError, TypeError):
        return ""
    packaged = {spec.name: spec.split for spec in packaged_objects()}
    added = sorted(
        (str(e["name"]), str(e.get("split")), str(e.get("category")), str(e.get("folder")))
        for e in entries
        if packaged.get(e["name"]) != e.get("split")
    )
    missing = sorted(set(packaged) - {e["name"] for e in entries})
    if not added and not missing:
        return ""
    return hashlib.sha256(json.dumps([added, missing]).encode()).hexdigest()[:12]
