"""Turning one source object into one complete cache folder (runs in a worker process)."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import tempfile
import time
from pathlib import Path

from ocplace.errors import AssetBuildError
from ocplace.paths import honour_umask
from ocplace.sim.library import processing, writers
from ocplace.sim.library.checksums import damage, read_checked, write_checksums
from ocplace.sim.library.config import LibraryConfig
from ocplace.sim.library.meshes import load_mesh
from ocplace.sim.library.metadata import ObjectSpec
from ocplace.sim.library.records import ASSET_FILE, asset_from_json, asset_to_json
from ocplace.sim.library.shape_descriptor import write_descriptor
from ocplace.sim.library.sources import SourceFiles
from ocplace.sim.library.types import ObjectAsset
from ocplace.sim.vectors import vec4

SIZE_RANGE = (0.005, 0.6)  # metres, largest extent; outside it the scale is surely wrong


@dataclasses.dataclass(frozen=True)
class ObjectResult:
    name: str
    status: str  # "ok" or "failed"
    reason: str
    seconds: float
    asset: ObjectAsset | None


def _check_size(name: str, extents) -> None:
    largest = max(extents)
    if not SIZE_RANGE[0] <= largest <= SIZE_RANGE[1]:
        raise AssetBuildError(
            f"{name} is {largest:.3f} m across after scaling, outside {SIZE_RANGE} m: set its `scale` in the metadata"
        )


def _write_object(directory: Path, spec: ObjectSpec, files: SourceFiles, config: LibraryConfig) -> ObjectAsset:
    full = load_mesh(files)
    full = processing.rest_on_table(
        processing.weld(processing.orient(full, spec.scale or files.scale, files.rotation, spec.rotate))
    )
    mesh = processing.decimate(full, config.max_faces)
    extents = processing.extents(mesh.vertices)
    _check_size(spec.name, extents)
    rgba = files.rgba
    if mesh.texture is not None:
        texture = processing.prepare_texture(mesh.texture, config.texture_px, spec.tint)
        texture.save(directory / writers.TEXTURE_PNG)
        rgba = (1.0, 1.0, 1.0, rgba[3])
    hulls = _collision_hulls(full, spec, config)
    mass = processing.mass_properties(hulls, config.density)
    writers.write_visual_obj(directory, mesh)
    write_descriptor(directory, [(mesh.vertices, mesh.faces)])
    for index, hull in enumerate(hulls):
        writers.write_hull_obj(directory / writers.hull_filename(index), hull)
    textured = mesh.texture is not None
    (directory / writers.MJCF_FILE).write_text(writers.mjcf_text(spec.name, textured, rgba, len(hulls), mass))
    (directory / writers.URDF_FILE).write_text(writers.urdf_text(spec.name, textured, rgba, len(hulls), mass))
    _check_mujoco(directory / writers.MJCF_FILE)
    return ObjectAsset(
        name=spec.name,
        human_name=spec.human_name,
        synonyms=spec.synonyms,
        category=spec.category,
        split=spec.split,
        source=f"{spec.source}:{spec.path}",
        licence=spec.licence,
        directory=directory,
        visual_mesh=directory / writers.VISUAL_OBJ,
        texture=directory / writers.TEXTURE_PNG if textured else None,
        rgba=vec4(rgba),
        hulls=tuple(directory / writers.hull_filename(i) for i in range(len(hulls))),
        mjcf=directory / writers.MJCF_FILE,
        urdf=directory / writers.URDF_FILE,
        extents=extents,
        mass=mass.mass,
    )


def _collision_hulls(full, spec: ObjectSpec, config: LibraryConfig) -> list[processing.Hull]:
    """One hull for nearly convex objects (cans, boxes, bottles), coacd pieces otherwise."""
    shape, closed = processing.collision_input(full, config.collision_faces)
    if spec.single_hull or processing.is_nearly_convex(shape, config.convex_ratio):
        return processing.convex_hull(shape)
    settings = config.coacd
    if spec.coacd_threshold is not None:
        settings = dataclasses.replace(settings, threshold=spec.coacd_threshold)
    return processing.decompose(shape, closed, settings)


def _check_mujoco(mjcf: Path) -> None:
    import mujoco

    try:
        mujoco.MjModel.from_xml_path(str(mjcf))
    except ValueError as error:
        raise AssetBuildError(f"MuJoCo rejects the written model: {error}") from error


def build_object(
    spec: ObjectSpec, files: SourceFiles, config: LibraryConfig, target: Path, tmp_root: Path
) -> ObjectResult:
    """Builds into a private temp folder, then renames it onto `target` in one step.

    A failure, crash or kill leaves at most a temp folder, which no reader ever uses.
    """
    start = time.perf_counter()
    tmp_root.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix=f"{target.name}.{os.getpid()}.", dir=tmp_root))
    try:
        asset = _write_object(work, spec, files, config)
        seconds = time.perf_counter() - start
        record = asset_to_json(asset) | {"build_seconds": round(seconds, 2)}
        (work / ASSET_FILE).write_text(json.dumps(record, indent=1) + "\n")
        write_checksums(work)
        if damage(target):  # else a concurrent build finished it first
            if target.exists():  # a folder whose files do not match its checksums is never used
                shutil.rmtree(target)
            target.parent.mkdir(parents=True, exist_ok=True)
            honour_umask(work)
            os.rename(work, target)
        asset = asset_from_json(read_checked(target), target)
        return ObjectResult(spec.name, "ok", "", seconds, asset)
    except Exception as error:  # one bad object must not stop the build
        reason = str(error) if isinstance(error, AssetBuildError) else f"{type(error).__name__}: {error}"
        return ObjectResult(spec.name, "failed", reason, time.perf_counter() - start, None)
    finally:
        shutil.rmtree(work, ignore_errors=True)
