"""The cache layout and the JSON form of its records (per-object `asset.json`, `manifest.json`)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from ocplace.paths import inside
from ocplace.sim.library.types import ObjectAsset, VisualPart

OBJECTS_DIRNAME = "objects"
TEXTURES_DIRNAME = "textures"
TMP_DIRNAME = "tmp"
MANIFEST_FILE = "manifest.json"
ASSET_FILE = "asset.json"  # written last inside an object's folder: its presence marks it complete
MANIFEST_VERSION = 1


_OBJECT_FIELDS: dict[str, type | tuple[type, ...]] = {"name": str, "status": str, "folder": (str, type(None))}
_TEXTURE_FIELDS: dict[str, type | tuple[type, ...]] = {"name": str, "file": str, "split": str}


def manifest_problem(manifest: object) -> str | None:
    """What keeps `manifest` (decoded JSON) from being a library manifest this version reads; None if nothing."""
    if not isinstance(manifest, dict):
        return f"it is a JSON {type(manifest).__name__}, not an object"
    if manifest.get("version") != MANIFEST_VERSION:
        return "it is from another ocplace version"
    for key, fields in (("objects", _OBJECT_FIELDS), ("textures", _TEXTURE_FIELDS)):
        entries = manifest.get(key)
        if not isinstance(entries, list):
            return f"it has no {key!r} list"
        for index, entry in enumerate(entries):
            if not isinstance(entry, dict) or not all(isinstance(entry.get(f), kind) for f, kind in fields.items()):
                return f"{key}[{index}] is not an entry with {', '.join(fields)}"
    return None


def asset_to_json(asset: ObjectAsset) -> dict:
    """Paths relative to the object's folder, so a cache can be moved as a whole."""
    record = {}
    for field in dataclasses.fields(asset):
        value = getattr(asset, field.name)
        if field.name == "directory":
            continue
        if isinstance(value, Path):  # Path(): none (an arena-only object has no PyBullet model)
            value = None if value == Path() else value.relative_to(asset.directory).as_posix()
        elif field.name == "hulls":
            value = [p.relative_to(asset.directory).as_posix() for p in value]
        elif field.name == "parts":
            value = [_part_to_json(part, asset.directory) for part in value]
        elif isinstance(value, tuple):
            value = list(value)
        record[field.name] = value
    return record


def asset_from_json(record: dict, directory: Path) -> ObjectAsset:
    """The asset an `asset.json` describes; ValueError if it names a file outside `directory`."""

    def path(value):
        return None if value is None else inside(directory, value)

    return ObjectAsset(
        name=record["name"],
        human_name=record["human_name"],
        synonyms=tuple(record["synonyms"]),
        category=record["category"],
        split=record["split"],
        source=record["source"],
        licence=record["licence"],
        directory=directory,
        visual_mesh=path(record["visual_mesh"]),
        texture=path(record["texture"]),
        rgba=tuple(record["rgba"]),
        hulls=tuple(inside(directory, p) for p in record["hulls"]),
        mjcf=path(record["mjcf"]) or Path(),
        urdf=path(record["urdf"]) or Path(),
        extents=tuple(record["extents"]),
        mass=float(record["mass"]),
        parts=tuple(
            VisualPart(inside(directory, part["mesh"]), path(part["texture"]), tuple(part["rgba"]))
            for part in record.get("parts", ())
        ),
    )


def _part_to_json(part: VisualPart, directory: Path) -> dict:
    texture = None if part.texture is None else part.texture.relative_to(directory).as_posix()
    return {"mesh": part.mesh.relative_to(directory).as_posix(), "texture": texture, "rgba": list(part.rgba)}
