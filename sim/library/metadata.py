"""Hand-written object metadata shipped in `ocplace.assets`: names, splits, sizes, textures.

`objects.json` lists every packaged object: where it comes from, what instructions call it,
its split, and the corrections its source needs (scale, rotation to its stable pose, tint).
`cliport_gso.json` holds CLIPort's Google-Scanned-Objects split; `textures.json` the table
textures.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import re
from importlib import resources

from ocplace.errors import AssetBuildError
from ocplace.sim.vectors import vec3
from ocplace.vocabulary import LIBRARY_SPLITS

CLIPORT_SPLITS = ("seen", "unseen")


@dataclasses.dataclass(frozen=True)
class ObjectSpec:
    """One object to build: its identity and how to turn its source into a library object.

    `scale` maps source units to metres (None keeps the source's own scale: the MJCF or URDF
    mesh scale); `rotate` is a list of (axis, degrees) turns applied after the source's own
    orientation, bringing the object upright into its stable resting pose; `tint` recolours a
    texture (grey level times this colour) for colour variants whose source only sets a
    flat colour.
    """

    name: str
    human_name: str
    synonyms: tuple[str, ...]
    category: str
    split: str  # one of LIBRARY_SPLITS
    source: str  # "libero", "pybullet", "robosuite", "gso" or "catalogue"
    path: str  # relative to the source's root; gso and catalogue: to `base`
    licence: str
    scale: tuple[float, float, float] | None = None
    rotate: tuple[tuple[str, float], ...] = ()
    tint: tuple[float, float, float] | None = None
    texture: str | None = None  # texture file override, relative to the object's folder
    rgba: tuple[float, float, float, float] | None = None  # colour override, untextured
    coacd_threshold: float | None = None  # per-object override of CoacdSettings.threshold
    single_hull: bool = False  # collide with one convex hull (small objects with fussy detail)
    # gso and catalogue: the folder `path` (and `texture`) are relative to. Never part of the key: the same files
    # from another folder are the same object.
    base: str = ""

    def key_fields(self) -> dict:
        """The fields that define the built object (part of its cache key): content, never where it lies."""
        fields = dataclasses.asdict(self)
        del fields["base"]
        return fields


@dataclasses.dataclass(frozen=True)
class TextureSpec:
    name: str
    source: str
    path: str
    split: str


def _read_json(name: str) -> dict:
    return json.loads(resources.files("ocplace.assets").joinpath(name).read_text("utf-8"))


def _as_scale(value) -> tuple[float, float, float] | None:
    if value is None:
        return None
    if isinstance(value, (int, float)):
        return (float(value),) * 3
    return vec3(value)


def _object_spec(entry: dict, licences: dict[str, str]) -> ObjectSpec:
    if entry["split"] not in LIBRARY_SPLITS:
        raise AssetBuildError(
            f"objects.json: {entry['name']} has split {entry['split']!r}; use one of {LIBRARY_SPLITS}"
        )
    folder = f"{entry['source']}:{entry['path'].split('/')[0]}"
    return ObjectSpec(
        name=entry["name"],
        human_name=entry["human_name"],
        synonyms=tuple(entry.get("synonyms", ())),
        category=entry["category"],
        split=entry["split"],
        source=entry["source"],
        path=entry["path"],
        licence=entry.get("licence") or licences.get(folder) or licences[entry["source"]],
        scale=_as_scale(entry.get("scale")),
        rotate=tuple((axis, float(deg)) for axis, deg in entry.get("rotate", ())),
        tint=tuple(entry["tint"]) if entry.get("tint") else None,
        texture=entry.get("texture"),
        rgba=tuple(entry["rgba"]) if entry.get("rgba") else None,
        coacd_threshold=entry.get("coacd_threshold"),
        single_hull=bool(entry.get("single_hull", False)),
    )


@functools.cache
def packaged_objects() -> tuple[ObjectSpec, ...]:
    """Every object listed in `objects.json`, in file order."""
    data = _read_json("objects.json")
    return tuple(_object_spec(entry, data["licences"]) for entry in data["objects"])


@functools.cache
def table_textures() -> tuple[TextureSpec, ...]:
    data = _read_json("textures.json")
    return tuple(TextureSpec(**entry) for entry in data["textures"])


@functools.cache
def cliport_gso() -> dict:
    """CLIPort's GSO objects: `{"seen": [...], "unseen": [...], "categories": {...}}`."""
    return _read_json("cliport_gso.json")


def slug(text: str) -> str:
    """`"Black Shoe-With Green_Stripes"` -> `"black_shoe_with_green_stripes"`."""
    return re.sub(r"[^a-z0-9]+", "_", text.lower()).strip("_")


def hashed_split(name: str, unseen_fraction: float = 0.3) -> str:
    """A stable split for an object no list mentions (about 70/30)."""
    digest = hashlib.sha256(name.encode("utf-8")).digest()
    return "unseen" if digest[0] / 256.0 < unseen_fraction else "seen"


def gso_identity(directory_name: str, pbtxt_name: str | None) -> dict:
    """Name, human name, category and split of a GSO-layout object.

    CLIPort's names ("black shoe with green stripes") are matched on the directory name, so a
    directory named after a CLIPort object gets CLIPort's split.
    """
    cliport = cliport_gso()
    by_slug = {slug(n): (n, split) for split in CLIPORT_SPLITS for n in cliport[split]}
    name = slug(directory_name)
    if name in by_slug:
        human, split = by_slug[name]
        return {
            "name": name,
            "human_name": human,
            "category": cliport["categories"].get(human, "object"),
            "split": split,
        }
    human = (pbtxt_name or directory_name).replace("_", " ").lower().strip()
    return {"name": name, "human_name": human, "category": "object", "split": hashed_split(name)}
