"""Converting one catalogue model (or one image as a cut-out, `sim.corpus.cutout`) into an arena object: one
visual mesh per material, one convex hull.

Sweet Home 3D models are Y-up, in arbitrary units; the catalogue gives the size the model is
stretched to (width along x, height along y, depth along z, after `modelRotation`). We do the same,
turn the result Z-up, shrink it uniformly to at most `max_extent_m` (the benchmark's largest training
object) and rest it on z = 0, centred like a library object. Files inside the archive are read only
by member name, through `member_name`, so an MTL that names `../../x` cannot reach anything.
"""

from __future__ import annotations

import dataclasses
import io
import json
import os
import posixpath
import shutil
import tempfile
import zipfile
from pathlib import Path

import mujoco
import numpy as np
import trimesh
from PIL import Image

from ocplace.errors import CorpusError
from ocplace.paths import honour_umask, unwritable
from ocplace.sim.corpus import cutout
from ocplace.sim.corpus.catalogue import CatalogueEntry, member_name, read_member
from ocplace.sim.corpus.cutout_sources import CUTOUT_CATALOGUES
from ocplace.sim.corpus.selection import SelectionRule, head_noun
from ocplace.sim.library import processing
from ocplace.sim.library.checksums import read_checked, write_checksums
from ocplace.sim.library.meshes import TexturedMesh
from ocplace.sim.library.records import ASSET_FILE, asset_from_json, asset_to_json
from ocplace.sim.library.shape_descriptor import write_descriptor
from ocplace.sim.library.types import CORPUS_SPLIT, ObjectAsset, VisualPart
from ocplace.sim.library.writers import hull_filename, write_hull_obj

# Sweet Home 3D's y-up frame (x right, z towards the viewer) to ours (x right, y away, z up).
_Y_UP_TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
MJCF_FILE = "object.xml"


@dataclasses.dataclass(frozen=True)
class ConversionConfig:
    """How a selected model becomes an arena object (part of each converted model's cache key)."""

    max_extent_m: float = 0.22  # the seen split's largest object (the plate)
    max_faces: int = 20_000  # decimated above this, over all parts, in proportion
    texture_px: int = 256  # crops show an object at about 100 px
    density: float = 400.0  # kg/m^3 of the hull: only for settling
    rule: SelectionRule = SelectionRule()


@dataclasses.dataclass(frozen=True)
class ConversionResult:
    key: str
    status: str  # "ok" or "skipped"
    reason: str
    asset: ObjectAsset | None


class _ArchiveResolver(trimesh.resolvers.Resolver):
    """Serves the members of one model's folder to trimesh's OBJ/MTL loader; remembers what it could not."""

    def __init__(self, archive: zipfile.ZipFile, folder: str):
        self.archive, self.folder = archive, folder
        self.missing: list[str] = []

    def get(self, name: str) -> bytes:
        try:
            return read_member(self.archive, member_name(name, self.folder))
        except CorpusError as error:
            self.missing.append(f"{name} ({error})")
            raise KeyError(name) from None

    def keys(self):
        return iter(())

    def write(self, name, data):
        raise CorpusError("catalogues are read-only")

    def namespaced(self, namespace):
        return self


def _parts(scene: trimesh.Scene) -> list[TexturedMesh]:
    parts = []
    for geometry in scene.dump():
        if not isinstance(geometry, trimesh.Trimesh) or len(geometry.faces) == 0:
            continue
        material = getattr(geometry.visual, "material", None)
        image = getattr(material, "image", None)
        uv = getattr(geometry.visual, "uv", None)
        diffuse = getattr(material, "diffuse", None)
        red, green, blue = (float(c) / 255.0 for c in diffuse[:3]) if diffuse is not None else (0.7, 0.7, 0.7)
        textured = image is not None and uv is not None and len(uv) == len(geometry.vertices)
        parts.append(
            TexturedMesh(
                np.asarray(geometry.vertices, np.float64),
                np.asarray(geometry.faces, np.int64),
                np.asarray(uv, np.float64) if textured else None,
                image.convert("RGB") if image is not None and textured else None,
                (red, green, blue, 1.0),
            )
        )
    return parts


def load_parts(archive: zipfile.ZipFile, entry: CatalogueEntry) -> list[TexturedMesh]:
    """The model's meshes, one per material; CorpusError for a model that cannot be used whole."""
    folder = posixpath.dirname(entry.model)
    resolver = _ArchiveResolver(archive, folder)
    try:
        data = read_member(archive, entry.model)
        scene = trimesh.load(
            io.BytesIO(data), file_type="obj", resolver=resolver, group_material=True, force="scene", process=False
        )
        assert isinstance(scene, trimesh.Scene), "force='scene' loads a scene"
        parts = _parts(scene)
    except (KeyError, OSError, ValueError, IndexError, zipfile.BadZipFile, EOFError) as error:
        raise CorpusError(f"cannot load {entry.model}: {type(error).__name__}: {error}") from error
    if resolver.missing:
        raise CorpusError(f"{entry.model} names files its archive lacks or may not read: {', '.join(resolver.missing)}")
    if not parts:
        raise CorpusError(f"{entry.model} holds no triangles")
    if not all(np.isfinite(part.vertices).all() for part in parts):
        raise CorpusError(f"{entry.model} has non-finite vertices")
    return parts


def _transform(parts: list[TexturedMesh], entry: CatalogueEntry, config: ConversionConfig) -> list[TexturedMesh]:
    """Rotated, stretched to the catalogue size, Z-up, shrunk to `max_extent_m`, resting on z = 0."""
    rotation = np.eye(3) if entry.rotation is None else np.array(entry.rotation).reshape(3, 3)
    rotated = [part.vertices @ rotation.T for part in parts]
    points = np.concatenate(rotated)
    span = points.max(axis=0) - points.min(axis=0)
    if (span <= 1e-9).any():
        raise CorpusError(f"{entry.model} is flat along an axis (extent {span})")
    width, depth, height = (s / 100.0 for s in entry.size_cm)
    stretch = np.array([width, height, depth]) / span
    shrink = min(1.0, config.max_extent_m / max(width, depth, height))
    moved = [(vertices * stretch) @ _Y_UP_TO_Z_UP.T * shrink for vertices in rotated]
    points = np.concatenate(moved)
    low, high = points.min(axis=0), points.max(axis=0)
    offset = np.array([(low[0] + high[0]) / 2, (low[1] + high[1]) / 2, low[2]])
    mirror = np.linalg.det(rotation) < 0  # a mirror flips the winding (the rest turns and stretches)
    return [
        dataclasses.replace(part, vertices=vertices - offset, faces=part.faces[:, ::-1] if mirror else part.faces)
        for part, vertices in zip(parts, moved, strict=True)
    ]


def _decimated(parts: list[TexturedMesh], max_faces: int) -> list[TexturedMesh]:
    total = sum(len(part.faces) for part in parts)
    if total <= max_faces:
        return parts
    return [processing.decimate(part, max(32, len(part.faces) * max_faces // total)) for part in parts]


def _write_obj(path: Path, mesh: TexturedMesh) -> None:
    buffer = io.StringIO()
    np.savetxt(buffer, mesh.vertices, fmt="v %.6f %.6f %.6f")
    faces = mesh.faces + 1
    if mesh.uv is not None:
        np.savetxt(buffer, mesh.uv, fmt="vt %.6f %.6f")
        np.savetxt(buffer, np.repeat(faces, 2, axis=1), fmt="f %d/%d %d/%d %d/%d")
    else:
        np.savetxt(buffer, faces, fmt="f %d %d %d")
    path.write_text(buffer.getvalue())


def _standalone_mjcf(asset_parts: list[VisualPart], hull: Path, mass: float) -> str:
    """A one-body model of the converted object: compiling it is the check that MuJoCo can use the files."""
    assets, geoms = [], []
    for k, part in enumerate(asset_parts):
        texture = ""
        if part.texture is not None:
            assets.append(f'<texture name="t{k}" type="2d" file="{part.texture.name}"/>')
            texture = f' texture="t{k}"'
        assets.append(f'<material name="m{k}"{texture} rgba="{" ".join(map(str, part.rgba))}"/>')
        assets.append(f'<mesh name="v{k}" file="{part.mesh.name}" inertia="shell"/>')
        geoms.append(f'<geom type="mesh" mesh="v{k}" material="m{k}" contype="0" conaffinity="0" density="0"/>')
    assets.append(f'<mesh name="hull" file="{hull.name}"/>')
    return (
        '<mujoco model="corpus_object">\n  <asset>\n    '
        + "\n    ".join(assets)
        + '\n  </asset>\n  <worldbody>\n    <body name="object">\n      <freejoint/>\n      '
        + f'<geom type="mesh" mesh="hull" mass="{mass:.6f}"/>\n      '
        + "\n      ".join(geoms)
        + "\n    </body>\n  </worldbody>\n</mujoco>\n"
    )


def _write_catalogue_model(
    directory: Path, entry: CatalogueEntry, archive_path: Path, licence: str, config: ConversionConfig
) -> ObjectAsset:
    with zipfile.ZipFile(archive_path) as archive:
        parts = load_parts(archive, entry)
    faces = sum(len(part.faces) for part in parts)
    problem = config.rule.faces_problem(faces)
    if problem:
        raise CorpusError(problem)
    parts = _decimated(_transform(parts, entry, config), config.max_faces)
    return write_object(directory, parts, entry, f"sweethome3d:{entry.catalogue}:{entry.model}", licence, config)


def _write_cutout(directory: Path, entry: CatalogueEntry, image_path: Path, licence: str, config: ConversionConfig):
    try:
        with Image.open(image_path) as image:
            rgb, mask = cutout.mask_of(image)
    except (OSError, ValueError, Image.DecompressionBombError) as error:
        raise CorpusError(f"cannot read the image: {type(error).__name__}: {error}") from error
    texture = cutout.filled_texture(rgb, mask)
    extent, _, thickness = (s / 100.0 for s in entry.size_cm)
    part = cutout.cutout_mesh(mask, texture, min(extent, config.max_extent_m), thickness)
    return write_object(directory, [part], entry, f"{entry.catalogue}:{entry.model}", licence, config)


def write_object(
    directory: Path, parts: list[TexturedMesh], entry: CatalogueEntry, source: str, licence: str, config
) -> ObjectAsset:
    """Writes `parts` (in the object frame) as one arena object in `directory`: a mesh and texture per part, the
    convex hull, the standalone MJCF (compiled as a check); CorpusError when MuJoCo cannot use them."""
    visual = []
    for k, part in enumerate(parts):
        mesh_path = directory / f"part_{k:02d}.obj"
        _write_obj(mesh_path, part)
        texture = None
        if part.texture is not None:
            texture = directory / f"part_{k:02d}.png"
            processing.prepare_texture(part.texture, config.texture_px).save(texture)
        visual.append(VisualPart(mesh_path, texture, part.rgba))
    points = np.concatenate([part.vertices for part in parts])
    write_descriptor(directory, [(part.vertices, part.faces) for part in parts])
    try:
        hull = trimesh.convex.convex_hull(points)
    except Exception as error:  # qhull's own error types
        raise CorpusError(f"no convex hull: {error}") from error
    if not hull.is_volume or hull.volume <= 0:
        raise CorpusError("its convex hull has no volume")
    hull_path = directory / hull_filename(0)
    write_hull_obj(hull_path, processing.Hull(np.asarray(hull.vertices), np.asarray(hull.faces)))
    mass = config.density * float(hull.volume)
    mjcf = directory / MJCF_FILE
    mjcf.write_text(_standalone_mjcf(visual, hull_path, mass))
    try:
        mujoco.MjModel.from_xml_path(str(mjcf))
    except ValueError as error:
        raise CorpusError(f"MuJoCo rejects the converted model: {error}") from error
    return ObjectAsset(
        name=entry.key,
        human_name=entry.name.lower(),
        synonyms=(),
        category=head_noun(entry.name),
        split=CORPUS_SPLIT,
        source=source,
        licence=licence,
        directory=directory,
        visual_mesh=visual[0].mesh,
        texture=visual[0].texture,
        rgba=visual[0].rgba,
        hulls=(hull_path,),
        mjcf=mjcf,
        urdf=Path(),
        extents=processing.extents(points),
        mass=mass,
        parts=tuple(visual[1:]),
    )


# Not a skip: nothing is wrong with the model, and a skip is remembered by every later build.
CACHE_HINT = "and rerun `ocplace corpus build`: the models converted so far are kept"


def convert_model(
    entry: CatalogueEntry, source: Path, licence: str, config: ConversionConfig, target: Path, tmp_root: Path
) -> ConversionResult:
    """Converts `entry` of `source` (a catalogue archive, or an image for a cut-out source's catalogue) into a private
    temp folder, then renames it onto `target` in one step (a kill leaves at most a temp folder, which no reader
    uses; `checksums.json`, over every other file, is written last)."""
    write = _write_cutout if entry.catalogue in CUTOUT_CATALOGUES else _write_catalogue_model
    work = None
    try:
        tmp_root.mkdir(parents=True, exist_ok=True)
        work = Path(tempfile.mkdtemp(prefix=f"{target.name}.{os.getpid()}.", dir=tmp_root))
        asset = write(work, entry, source, licence, config)
        (work / ASSET_FILE).write_text(json.dumps(asset_to_json(asset), indent=1) + "\n")
        write_checksums(work)
        if target.exists():  # a folder without its asset.json is partial: never used
            shutil.rmtree(target)
        target.parent.mkdir(parents=True, exist_ok=True)
        honour_umask(work)
        os.rename(work, target)  # just written and hashed: its paths moved with it, no need to hash it again
        return ConversionResult(
            entry.key, "ok", "", asset_from_json(json.loads((target / ASSET_FILE).read_text()), target)
        )
    except Exception as error:  # one bad model must not stop the corpus; a full or read-only disk stops it
        if isinstance(error, OSError) and (typed := unwritable(error, target, CACHE_HINT)):
            raise typed from error
        reason = str(error) if isinstance(error, CorpusError) else f"{type(error).__name__}: {error}"
        return ConversionResult(entry.key, "skipped", reason, None)
    finally:
        if work is not None:
            shutil.rmtree(work, ignore_errors=True)


def read_converted(directory: Path) -> ObjectAsset:
    """The converted model in `directory`, its files checked against their checksums; ValueError/OSError/KeyError
    when it is missing, incomplete or damaged."""
    return asset_from_json(read_checked(directory), directory)
