"""A user catalogue's built objects, read from `<cache>/catalogues/<name>`, and the library a dataset of its subsets
is made and scored with: the catalogue's objects, the benchmark's table textures and, when asked, the benchmark's
objects of one split as distractors. The benchmark's own library (`load_library()`) never holds them.
"""

from __future__ import annotations

import types
from pathlib import Path

from ocplace.errors import CatalogueError, LibraryNotBuilt
from ocplace.paths import catalogues_cache
from ocplace.sim.library.library import Library, load_library, load_library_at
from ocplace.sim.library.user_catalogue import Catalogue, subset_name_problem
from ocplace.vocabulary import LIBRARY_SPLITS


def catalogue_root(name: str, cache: str | Path | None = None) -> Path:
    problem = subset_name_problem(name)
    if problem:
        raise CatalogueError(f"no catalogue can be named so: {problem}")
    return catalogues_cache(cache) / name


def catalogue_record(catalogue: Catalogue) -> dict:
    """What a built catalogue, and every dataset made from it, records of it: name, content hash, subsets."""
    return {
        "name": catalogue.name,
        "content_hash": catalogue.content_hash,
        "subsets": {s.name: {"new_categories": s.new_categories} for s in catalogue.subsets},
    }


def load_catalogue(record: dict, cache: str | Path | None = None) -> Library:
    """The built objects of the catalogue `record` names (`catalogue_record`), checked to be that content."""
    name = record.get("name") if isinstance(record, dict) else None
    how = f"build it: `ocplace assets build --catalogue FILE`, FILE the catalogue named {name!r}"
    try:
        library = load_library_at(catalogue_root(str(name), cache))
    except LibraryNotBuilt as error:
        raise CatalogueError(f"the catalogue {name!r} is not built ({error}); {how}") from None
    built = library.manifest.get("catalogue") or {}
    if built.get("content_hash") != record.get("content_hash"):
        raise CatalogueError(
            f"the catalogue {name!r} built in {library.root} is other content (hash "
            f"{str(built.get('content_hash'))[:12]}) than this needs ({str(record.get('content_hash'))[:12]}); {how}"
        )
    failed = [e["name"] for e in library.manifest["objects"] if e["status"] != "ok"]
    if failed:
        raise CatalogueError(
            f"catalogue {name!r}: {', '.join(failed)} failed to build; `ocplace assets list "
            f"--catalogue {name}` shows why"
        )
    return library


def subset_library(record: dict, distractors: str | None = None, cache: str | Path | None = None) -> Library:
    """The catalogue's objects with the benchmark's table textures, and its `distractors` split's objects if named."""
    if distractors is not None and distractors not in LIBRARY_SPLITS:
        raise CatalogueError(
            f"distractors come from a library split ({', '.join(LIBRARY_SPLITS)}), not {distractors!r}"
        )
    benchmark = load_library(cache)
    own = load_catalogue(record, cache)
    objects = dict(own.objects)
    if distractors is not None:
        objects |= {name: benchmark.objects[name] for name in benchmark.names(distractors)}
    return Library(
        objects=types.MappingProxyType(objects),
        textures=benchmark.textures,
        root=own.root,
        manifest=own.manifest,
    )
