"""Reading Sweet Home 3D furniture catalogues (`.sh3f`): a zip holding OBJ+MTL models, their textures
and `PluginFurnitureCatalog.properties`, which names each model and gives its size in centimetres.

Every member name is checked before it is read: an absolute name or a `..` segment is refused,
so a catalogue can never make us read (or write) outside itself.
"""

from __future__ import annotations

import dataclasses
import posixpath
import re
import zipfile
import zlib
from pathlib import Path

import numpy as np

from ocplace.errors import CorpusError
from ocplace.sim.vectors import vec3

PROPERTIES_FILE = "PluginFurnitureCatalog.properties"
# A catalogue is untrusted input: a member that declares or inflates to more than this is refused (the largest
# member of Debian's catalogues is about 40 MB).
MAX_MEMBER_BYTES = 256 << 20
_ESCAPE = re.compile(r"\\(u[0-9a-fA-F]{4}|.)")
_SIMPLE_ESCAPES = {"t": "\t", "n": "\n", "r": "\r", "f": "\f"}


@dataclasses.dataclass(frozen=True)
class CatalogueEntry:
    """One model of a catalogue, as its properties describe it."""

    catalogue: str  # the archive's stem, e.g. "Scopia"
    index: int  # N of `name#N`
    name: str  # English name, e.g. "Salt shaker"
    category: str  # the catalogue's room category, e.g. "Kitchen"
    size_cm: tuple[float, float, float]  # width (x), depth, height (up), as Sweet Home 3D scales the model
    model: str  # member name of the OBJ inside the archive
    rotation: tuple[float, ...] | None  # `modelRotation#N`: 9 numbers, row-major, applied before scaling
    creator: str

    @property
    def key(self) -> str:
        """A stable identifier: `scopia-042`."""
        return f"{re.sub(r'[^a-z0-9]+', '-', self.catalogue.lower()).strip('-')}-{self.index:03d}"


def _unescape(value: str) -> str:
    def replace(match: re.Match) -> str:
        code = match.group(1)
        if code.startswith("u") and len(code) == 5:
            return chr(int(code[1:], 16))
        return _SIMPLE_ESCAPES.get(code, code)

    return _ESCAPE.sub(replace, value)


def read_member(archive: zipfile.ZipFile, name: str) -> bytes:
    """The bytes of member `name`; CorpusError for a missing, damaged, encrypted, oddly compressed or oversized
    one (over `MAX_MEMBER_BYTES` as declared, or once inflated)."""
    try:
        if archive.getinfo(name).file_size > MAX_MEMBER_BYTES:
            raise CorpusError(f"{name} declares more than {MAX_MEMBER_BYTES:,} bytes")
        with archive.open(name) as member:
            data = member.read(MAX_MEMBER_BYTES + 1)
    except (KeyError, OSError, EOFError, zipfile.BadZipFile, zlib.error, RuntimeError, NotImplementedError) as error:
        # RuntimeError: an encrypted member; NotImplementedError: a compression method zipfile lacks
        raise CorpusError(f"cannot read {name}: {type(error).__name__}: {error}") from error
    if len(data) > MAX_MEMBER_BYTES:
        raise CorpusError(f"{name} inflates to more than {MAX_MEMBER_BYTES:,} bytes")
    return data


def _valid_text(text: str) -> str:
    """`text` with the UTF-16 surrogate pairs of Java's escapes joined; ValueError for a lone surrogate."""
    try:
        return text.encode("utf-16", "surrogatepass").decode("utf-16")
    except UnicodeDecodeError:
        raise ValueError(f"{text.encode('utf-8', 'backslashreplace').decode()!r} holds a lone surrogate") from None


def parse_properties(text: str) -> dict[str, str]:
    """The key/value pairs of a Java properties file (comments, continuation lines, escapes)."""
    pairs = {}
    logical = ""
    for raw in text.splitlines():
        line = raw.lstrip()
        if not logical and (not line or line[0] in "#!"):
            continue
        trailing = len(line) - len(line.rstrip("\\"))
        if trailing % 2 == 1:  # an odd number of backslashes continues the line
            logical += line[:-1]
            continue
        logical += line
        match = re.match(r"((?:\\.|[^=:\s])+)\s*[=:\s]\s*(.*)$", logical)
        if match:
            pairs[_unescape(match.group(1))] = _unescape(match.group(2))
        logical = ""
    return pairs


def member_name(reference: str, folder: str = "") -> str:
    """The archive member `reference` names: a catalogue path (`/scopia/cup/cup.obj`), or, with
    `folder`, a name an OBJ or MTL inside `folder` uses. CorpusError if it leads out of the archive
    (or out of `folder`)."""
    name = reference.replace("\\", "/")
    if folder:
        if name.startswith("/"):
            raise CorpusError(f"{reference!r} is an absolute path")
        name = posixpath.join(folder, name)
    normal = posixpath.normpath(name.lstrip("/") if not folder else name)
    if normal in ("", ".", "..") or normal.startswith(("../", "/")):
        raise CorpusError(f"{reference!r} leads out of the archive")
    if folder and not normal.startswith(folder.rstrip("/") + "/"):
        raise CorpusError(f"{reference!r} leads out of its model's folder {folder}")
    return normal


def _number(properties: dict[str, str], key: str) -> float:
    try:
        value = float(properties[key])
    except (KeyError, ValueError):
        return float("nan")
    return value


def _rotation(text: str | None) -> tuple[float, ...] | None:
    if not text:
        return None
    values = tuple(float(v) for v in text.split())
    if len(values) != 9 or not np.isfinite(values).all():
        raise ValueError(f"modelRotation {text!r} is not 9 finite numbers")
    return values


def read_entries(path: Path) -> tuple[list[CatalogueEntry], list[tuple[int, str, str]]]:
    """Every model of the catalogue at `path`, and `(index, name, why)` for each entry that cannot be read.

    CorpusError when the archive itself cannot be read (truncated, not a zip, no properties file).
    """
    path = Path(path)
    try:
        with zipfile.ZipFile(path) as archive:
            text = read_member(archive, PROPERTIES_FILE).decode("latin-1")
    except (OSError, zipfile.BadZipFile, EOFError, CorpusError) as error:
        raise CorpusError(f"cannot read the catalogue {path}: {error}") from error
    properties = parse_properties(text)
    indices = sorted({int(key[5:]) for key in properties if re.fullmatch(r"name#\d+", key)})
    entries, problems = [], []
    for index in indices:

        def get(field: str, index: int = index) -> str:
            return properties.get(f"{field}#{index}", "")

        try:
            entries.append(
                CatalogueEntry(
                    catalogue=path.stem,
                    index=index,
                    name=_valid_text(" ".join(get("name").split())),
                    category=_valid_text(get("category")),
                    size_cm=vec3(_number(properties, f"{k}#{index}") for k in ("width", "depth", "height")),
                    model=member_name(get("model")),
                    rotation=_rotation(get("modelRotation")),
                    creator=_valid_text(get("creator")),
                )
            )
        except (CorpusError, ValueError) as error:
            problems.append((index, get("name").encode("utf-8", "backslashreplace").decode(), str(error)))
    return entries, problems
