"""A user's own object catalogue: the objects file a lab writes for its meshes (docs/library.md, "Test on your own
objects").

The file is JSON in the schema of the packaged `assets/objects.json` plus what a user's meshes need (units, colour,
subset). Every problem of every entry is collected and reported at once, before any object is built. A catalogue's
objects never enter the library (`load_library()`), so no benchmark pool, and no pretraining pool, ever sees them;
they are built into a folder of their own (`user_catalogue_build.py`).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import re
from pathlib import Path

from ocplace.errors import AssetBuildError, CatalogueError, FileRefused
from ocplace.paths import file_sha256, read_json_bounded, regular_file
from ocplace.runtime.progress import progress_bar
from ocplace.sim.library.meshes import load_mesh
from ocplace.sim.library.metadata import ObjectSpec, packaged_objects
from ocplace.sim.library.process_object import SIZE_RANGE
from ocplace.sim.library.processing import extents, orient
from ocplace.sim.library.sources import gso_files, source_files
from ocplace.sim.vectors import vec3, vec4
from ocplace.vocabulary import OWN_SUBSET_PATTERN, RESERVED_NAMES

FORMAT = "ocplace-catalogue"
VERSION = 1
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}
MESH_SUFFIXES = (".obj", ".stl", ".ply")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
MAX_CATALOGUE_BYTES = 4 << 20  # a catalogue is a hand-written list; anything larger is not one
MAX_SOURCE_BYTES = 2 << 30  # a mesh or texture file; a scan of a tabletop object is far smaller
_NAME = re.compile(OWN_SUBSET_PATTERN)
_OBJECT_FIELDS = frozenset(
    (
        "name",
        "human_name",
        "synonyms",
        "category",
        "mesh",
        "gso",
        "texture",
        "units",
        "scale",
        "rotate",
        "rgba",
        "licence",
        "subset",
    )
)


@dataclasses.dataclass(frozen=True)
class Subset:
    """A subset a catalogue defines; `new_categories`: its objects' categories must be absent from training."""

    name: str
    new_categories: bool = False


@dataclasses.dataclass(frozen=True)
class Catalogue:
    """A validated catalogue: its objects as specs (split = their subset), and its content hash."""

    name: str
    path: Path  # the file, resolved
    subsets: tuple[Subset, ...]
    specs: tuple[ObjectSpec, ...]
    content_hash: str  # sha256 over the entries and every file's bytes, never over where they lie

    def subset(self, name: str) -> Subset:
        for subset in self.subsets:
            if subset.name == name:
                return subset
        named = ", ".join(s.name for s in self.subsets)
        raise CatalogueError(f"catalogue {self.name!r} ({self.path}) has no subset {name!r}; its subsets: {named}")


def subset_name_problem(name: object) -> str | None:
    """Why `name` cannot name a subset of a user's own (None when it can)."""
    if not isinstance(name, str) or not _NAME.fullmatch(name):
        return f"{name!r} is not a name of lowercase letters, digits and _ (starting with a letter, at most 48)"
    if name in RESERVED_NAMES:
        return f"{name!r} is a name of the benchmark's; choose another (for example 'lab_{name}')"
    return None


def read_catalogue(path: str | Path) -> Catalogue:
    """Reads and validates the catalogue at `path`: CatalogueError listing every problem, before any work."""
    path = Path(path).expanduser()
    data = _read_json(path)
    problems: list[str] = []
    base = path.resolve().parent
    name = data.get("name")
    problems += [f"name: {p}" for p in [subset_name_problem(name)] if p]
    subsets = _subsets(data, name, problems)
    entries = data.get("objects")
    if not isinstance(entries, list) or not entries:
        problems.append("objects: a non-empty list of objects is needed")
        entries = []
    specs = []
    # Each mesh is read to check it: a lab's scans can take a while, so the check shows its progress.
    for index, entry in enumerate(progress_bar(entries, desc="checking the catalogue", unit="obj")):
        label = f"objects[{index}]" + (f" ({entry.get('name')})" if isinstance(entry, dict) else "")
        entry_problems: list[str] = []
        spec = _spec(entry, base, subsets, entry_problems)
        if spec is not None and not entry_problems:
            _check_files(spec, entry_problems)
        problems += [f"{label}: {p}" for p in entry_problems]
        if spec is not None:
            specs.append(spec)
    problems += _clashes(specs, subsets)
    if problems or not isinstance(name, str):  # a name that is no text is one of the problems
        listed = "\n  - ".join(problems)
        raise CatalogueError(f"{path}: {len(problems)} problem(s); nothing was built:\n  - {listed}")
    return Catalogue(
        name=name,
        path=path.resolve(),
        subsets=tuple(subsets.values()),
        specs=tuple(specs),
        content_hash=content_hash(name, subsets.values(), specs),
    )


def _read_json(path: Path) -> dict:
    try:
        data = read_json_bounded(path, MAX_CATALOGUE_BYTES)
    except FileNotFoundError:
        raise CatalogueError(f"no catalogue {path}; docs/library.md shows one") from None
    except FileRefused as error:
        raise CatalogueError(f"{error}; give the catalogue's JSON file") from None
    except OSError as error:
        raise CatalogueError(f"cannot read the catalogue {path}: {error}") from error
    except ValueError as error:
        raise CatalogueError(f"{path} is not JSON ({error}); docs/library.md shows a catalogue") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT or data.get("version") != VERSION:
        raise CatalogueError(
            f'{path} is not an ocplace catalogue: it needs "format": "{FORMAT}" and "version": {VERSION} '
            '(docs/library.md, "Test on your own objects")'
        )
    return data


def _subsets(data: dict, name: object, problems: list[str]) -> dict[str, Subset]:
    """The catalogue's subsets: its `subsets` mapping, or one named after the catalogue."""
    given = data.get("subsets", {name: {}} if isinstance(name, str) else {})
    if not isinstance(given, dict) or not given:
        problems.append('subsets: a mapping {"NAME": {"new_categories": false}, ...} is needed')
        return {}
    subsets = {}
    for subset, options in given.items():
        problem = subset_name_problem(subset)
        if problem:
            problems.append(f"subsets: {problem}")
            continue
        options = options if isinstance(options, dict) else None
        if (
            options is None
            or set(options) - {"new_categories"}
            or not isinstance(options.get("new_categories", False), bool)
        ):
            problems.append(f'subsets.{subset}: give {{}} or {{"new_categories": true|false}}')
            continue
        subsets[subset] = Subset(subset, options.get("new_categories", False))
    return subsets


def _text(entry: dict, field: str, problems: list[str], required: bool = True) -> str | None:
    value = entry.get(field)
    if value is None and not required:
        return None
    if not isinstance(value, str) or not value.strip() or len(value) > 200:
        problems.append(f"{field}: {'missing' if value is None else 'not a short text'}" + _FIELD_HINTS.get(field, ""))
        return None
    return value.strip()


_FIELD_HINTS = {
    "licence": " (the licence you may use the mesh under, for example 'CC0' or 'own scan, all rights reserved')",
    "category": " (the noun people use, for example 'mug': new-category subsets are checked on it)",
    "human_name": " (what instructions call it, for example 'blue mug')",
}


def _spec(entry: object, base: Path, subsets: dict[str, Subset], problems: list[str]) -> ObjectSpec | None:
    if not isinstance(entry, dict):
        problems.append("an object is a JSON object with name, human_name, category, mesh, licence")
        return None
    unknown = sorted(set(entry) - _OBJECT_FIELDS)
    if unknown:
        problems.append(f"unknown field(s) {', '.join(unknown)}; the fields are {', '.join(sorted(_OBJECT_FIELDS))}")
    name = entry.get("name")
    if not isinstance(name, str) or not _NAME.fullmatch(name):
        problems.append(f"name: {name!r} is not lowercase letters, digits and _ (starting with a letter)")
    human_name, category = _text(entry, "human_name", problems), _text(entry, "category", problems)
    licence = _text(entry, "licence", problems)
    synonyms = entry.get("synonyms", [])
    if not isinstance(synonyms, list) or not all(isinstance(s, str) and s.strip() for s in synonyms):
        problems.append("synonyms: a list of texts")
        synonyms = []
    subset = entry.get("subset", next(iter(subsets), None) if len(subsets) == 1 else None)
    if subset not in subsets:
        problems.append(f"subset: {subset!r} is none of the catalogue's subsets ({', '.join(subsets) or 'none'})")
    source, relative = _source(entry, base, problems)
    texture = _relative_file(entry, "texture", base, IMAGE_SUFFIXES, problems) if "texture" in entry else None
    if source == "gso" and texture is not None:
        problems.append("texture: a GSO-layout folder brings its own (materials/textures/texture.png)")
    scale = _scale(entry, problems)
    rotate = _rotate(entry.get("rotate", []), problems)
    rgba = _rgba(entry.get("rgba"), problems)
    if problems or not (isinstance(name, str) and human_name and category and licence and isinstance(subset, str)):
        return None  # each of those missing is one of the problems
    return ObjectSpec(
        name=name,
        human_name=human_name,
        synonyms=tuple(s.strip() for s in synonyms),
        category=category,
        split=subset,
        source=source,
        path=relative,
        licence=licence,
        scale=scale,
        rotate=rotate,
        texture=texture,
        rgba=rgba,
        base=str(base),
    )


def _source(entry: dict, base: Path, problems: list[str]) -> tuple[str, str]:
    if ("mesh" in entry) == ("gso" in entry):
        problems.append('give exactly one of "mesh" (a mesh file) and "gso" (a Google-Scanned-Objects-layout folder)')
        return "", ""
    if "mesh" in entry:
        return "catalogue", _relative_file(entry, "mesh", base, MESH_SUFFIXES, problems) or ""
    folder = _relative(entry, "gso", base, problems)
    if folder is not None and not (folder / "meshes" / "model.obj").is_file():
        problems.append(f"gso: {entry['gso']!r} has no meshes/model.obj")
    return "gso", entry["gso"] if folder is not None else ""


def _relative(entry: dict, field: str, base: Path, problems: list[str]) -> Path | None:
    """`base / entry[field]`, resolved, when it exists inside `base`; else a problem and None."""
    value = entry.get(field)
    if not isinstance(value, str) or not value or Path(value).is_absolute():
        problems.append(f"{field}: a path relative to the catalogue's folder is needed, got {value!r}")
        return None
    try:
        resolved = (base / value).resolve(strict=True)
    except FileNotFoundError:
        problems.append(f"{field}: {value!r} does not exist in {base}")
        return None
    except (OSError, RuntimeError) as error:  # a symlink loop is RuntimeError before Python 3.13
        problems.append(f"{field}: {value!r} cannot be resolved ({error})")
        return None
    if not resolved.is_relative_to(base):
        problems.append(f"{field}: {value!r} leads out of the catalogue's folder {base}; copy the file into it")
        return None
    return resolved


def _relative_file(entry: dict, field: str, base: Path, suffixes: tuple[str, ...], problems: list[str]) -> str | None:
    resolved = _relative(entry, field, base, problems)
    if resolved is None:
        return None
    try:
        regular_file(resolved, MAX_SOURCE_BYTES)
    except FileRefused as error:
        problems.append(f"{field}: {error}")
        return None
    if resolved.suffix.lower() not in suffixes:
        problems.append(f"{field}: {entry[field]!r} is not one of {', '.join(suffixes)}")
        return None
    return entry[field]


def _scale(entry: dict, problems: list[str]) -> tuple[float, float, float] | None:
    if "units" in entry and "scale" in entry:
        problems.append('give "units" or "scale", not both')
        return None
    if "units" in entry:
        if entry["units"] not in UNITS:
            problems.append(f"units: {entry['units']!r} is none of {', '.join(UNITS)}")
            return None
        return (UNITS[entry["units"]],) * 3
    value = entry.get("scale", 1.0)
    values = [value] * 3 if isinstance(value, (int, float)) and not isinstance(value, bool) else value
    if (
        not isinstance(values, list)
        or len(values) != 3
        or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0 for v in values
        )
    ):
        problems.append(f"scale: a positive number or three (metres per mesh unit), got {value!r}")
        return None
    return vec3(values)


def _rotate(value: object, problems: list[str]) -> tuple[tuple[str, float], ...]:
    ok = isinstance(value, list) and all(
        isinstance(turn, list)
        and len(turn) == 2
        and turn[0] in ("x", "y", "z")
        and isinstance(turn[1], (int, float))
        and not isinstance(turn[1], bool)
        and math.isfinite(turn[1])
        for turn in value
    )
    if not ok or not isinstance(value, list):
        problems.append(f'rotate: a list of [axis, degrees] turns such as [["x", 90]], got {value!r}')
        return ()
    return tuple((axis, float(degrees)) for axis, degrees in value)


def _rgba(value: object, problems: list[str]) -> tuple[float, float, float, float] | None:
    if value is None:
        return None
    ok = (
        isinstance(value, list)
        and len(value) in (3, 4)
        and all(isinstance(v, (int, float)) and not isinstance(v, bool) and 0.0 <= v <= 1.0 for v in value)
    )
    if not ok or not isinstance(value, list):
        problems.append(f"rgba: three or four numbers in [0, 1] (red, green, blue, opacity), got {value!r}")
        return None
    return vec4([*value, 1.0][:4])


def _check_files(spec: ObjectSpec, problems: list[str]) -> None:
    """Reads the mesh (and texture): it must load, carry UVs when textured, and be a tabletop object's size."""
    try:
        files = source_files(spec) if spec.source == "catalogue" else gso_files(Path(spec.base) / spec.path)
        mesh = load_mesh(files)
    except AssetBuildError as error:
        problems.append(str(error).replace(spec.base + os.sep, ""))
        return
    scale = spec.scale or (1.0, 1.0, 1.0)
    largest = max(extents(orient(mesh, scale, files.rotation, spec.rotate).vertices))
    if not SIZE_RANGE[0] <= largest <= SIZE_RANGE[1]:
        problems.append(
            f"it is {largest:.4g} m across, outside a tabletop object's {SIZE_RANGE[0]}-{SIZE_RANGE[1]} m: "
            f"{_units_hint(largest / scale[0])}"
        )


def _units_hint(raw: float) -> str:
    """The units under which a mesh `raw` units across would be a tabletop object's size."""
    fitting = [unit for unit, factor in UNITS.items() if SIZE_RANGE[0] <= raw * factor <= SIZE_RANGE[1]]
    if fitting:
        return f'its mesh is {raw:.4g} units across; set "units": "{fitting[-1]}" (or "scale")'
    return f'its mesh is {raw:.4g} units across; set "scale" to the metres per mesh unit'


def _clashes(specs: list[ObjectSpec], subsets: dict[str, Subset]) -> list[str]:
    """Names shared with another object or the benchmark's; new-category subsets with a training category."""
    problems = []
    packaged = packaged_objects()
    taken = {s.name for s in packaged} | {s.human_name.lower() for s in packaged}
    seen: dict[str, str] = {}
    for spec in specs:
        for key in (spec.name, spec.human_name.lower()):
            if key in seen and seen[key] != spec.name:
                problems.append(f"{spec.name}: {key!r} is also {seen[key]}'s; each object needs its own")
            elif key in taken:
                problems.append(f"{spec.name}: {key!r} is a benchmark object's name; choose another")
            seen.setdefault(key, spec.name)
    names = [s.name for s in specs]
    problems += [f"{n}: listed {names.count(n)} times" for n in sorted(set(names)) if names.count(n) > 1]
    training = {s.category.lower() for s in packaged if s.split == "seen"}
    for spec in specs:
        if subsets.get(spec.split, Subset("")).new_categories and spec.category.lower() in training:
            problems.append(
                f"{spec.name}: category {spec.category!r} has training objects, so it cannot be in the new-category "
                f"subset {spec.split!r}; move it to a subset without new_categories or name its real category"
            )
    return problems


def content_hash(name: str, subsets, specs) -> str:
    """sha256 over the name, subsets, entries (paths relative to the file) and every source file's bytes."""
    digest = hashlib.sha256()
    entries = [spec.key_fields() for spec in specs]
    digest.update(json.dumps([name, [dataclasses.asdict(s) for s in subsets], entries], sort_keys=True).encode())
    for spec in specs:
        files = source_files(spec)
        for path in files.input_files():
            digest.update(path.name.encode())
            digest.update(bytes.fromhex(file_sha256(path)))  # streamed: a scan's mesh may be large
    return digest.hexdigest()
