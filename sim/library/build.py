"""Building the object library into the cache: keys, worker pool, textures, manifest."""

from __future__ import annotations

import contextlib
import dataclasses
import difflib
import hashlib
import json
import logging
from collections import Counter
from pathlib import Path

from PIL import Image

from ocplace.errors import AssetBuildError, UnknownObject
from ocplace.paths import (
    atomic_path,
    file_sha256,
    library_cache,
    refuse_links,
    remove_abandoned_tmp,
    remove_tree,
    write_text_atomic,
)
from ocplace.runtime import Executor, ExecutorConfig, Task, open_executor
from ocplace.runtime.progress import progress_bar
from ocplace.sim.library.catalogue_library import catalogue_record, catalogue_root
from ocplace.sim.library.checksums import CHECKSUMS_FILE, read_checked
from ocplace.sim.library.config import LibraryConfig, default_config
from ocplace.sim.library.library import Library, load_library, load_library_at
from ocplace.sim.library.metadata import ObjectSpec, packaged_objects, table_textures
from ocplace.sim.library.process_object import ObjectResult, build_object
from ocplace.sim.library.records import (
    MANIFEST_FILE,
    MANIFEST_VERSION,
    OBJECTS_DIRNAME,
    TEXTURES_DIRNAME,
    TMP_DIRNAME,
    asset_from_json,
    manifest_problem,
)
from ocplace.sim.library.sources import SourceFiles, gso_specs, libero_root, pybullet_root, source_files
from ocplace.sim.library.user_catalogue import Catalogue

PROCESSING_VERSION = 2  # bump when processing changes what is written: every object rebuilds (2: checksums)
_KEY_CHARS = 16

log = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True)
class _Job:
    spec: ObjectSpec
    files: SourceFiles | None
    key: str
    error: str = ""  # why the sources could not be located

    @property
    def folder(self) -> str:
        return f"{OBJECTS_DIRNAME}/{self.spec.name}-{self.key}"


def resolve_specs(config: LibraryConfig) -> list[ObjectSpec]:
    """The packaged objects plus every GSO-layout object, filtered by `config.objects`."""
    specs = list(packaged_objects())
    for directory in config.gso_dirs:
        specs += gso_specs(directory)
    for label, values in (("name", [s.name for s in specs]), ("human name", [s.human_name for s in specs])):
        duplicates = sorted(v for v, n in Counter(values).items() if n > 1)
        if duplicates:
            raise AssetBuildError(f"two objects share the {label} {', '.join(duplicates)}; rename one")
    if config.objects is None:
        return specs
    known = {s.name for s in specs}
    for name in config.objects:
        if name not in known:
            close = difflib.get_close_matches(name, sorted(known), n=5, cutoff=0.5)
            raise UnknownObject(f"no object {name!r} to build; close matches: {', '.join(close) or 'none'}")
    wanted = set(config.objects)
    return [s for s in specs if s.name in wanted]


def _hash_files(digest, paths) -> None:
    for path in paths:
        digest.update(path.name.encode())
        with open(path, "rb") as handle:
            while chunk := handle.read(1 << 20):
                digest.update(chunk)


def object_key(spec: ObjectSpec, files: SourceFiles, config: LibraryConfig) -> str:
    """Hash of the input files' bytes, the object's metadata, the settings and the code version."""
    settings = {
        "version": PROCESSING_VERSION,
        "settings": config.processing_settings(),
        "spec": spec.key_fields(),
        "source": {
            "scale": files.scale,
            "rotation": [round(float(v), 9) for v in files.rotation.ravel()],
            "rgba": files.rgba,
            "uv_origin": files.uv_origin,
        },
    }
    digest = hashlib.sha256(json.dumps(settings, sort_keys=True).encode())
    try:
        _hash_files(digest, files.input_files())
    except OSError as error:
        raise AssetBuildError(f"cannot read {spec.name}'s source files: {error}") from error
    return digest.hexdigest()[:_KEY_CHARS]


def _job(spec: ObjectSpec, config: LibraryConfig) -> _Job:
    try:
        files = source_files(spec)
        return _Job(spec, files, object_key(spec, files, config))
    except AssetBuildError as error:
        return _Job(spec, None, "unbuilt", str(error))


def _cached(root: Path, job: _Job) -> ObjectResult | None:
    directory = root / job.folder
    if not directory.exists():
        return None
    try:
        record = read_checked(directory)
        asset = asset_from_json(record, directory)
    except (OSError, ValueError, KeyError, TypeError) as error:  # damaged, or names files outside its folder
        log.warning("library object %s cannot be used (%s): it is built again", job.spec.name, error)
        return None
    return ObjectResult(job.spec.name, "ok", "", record.get("build_seconds", 0.0), asset)


def _run_jobs(jobs: list[_Job], config: LibraryConfig, root: Path, executor: Executor, progress: bool):
    """The result of every job; a job whose worker died (a native crash in coacd, say) is marked failed."""
    tmp_root = root / TMP_DIRNAME
    bar = progress_bar(total=len(jobs), desc="building objects", unit="obj", enabled=progress)
    handles = {
        executor.submit(Task(build_object, (job.spec, job.files, config, root / job.folder, tmp_root))): job
        for job in jobs
    }
    results, pending = [], list(handles)
    while pending:
        done, pending = executor.wait(pending)
        for handle in done:
            job = handles[handle]
            try:
                results.append(executor.result(handle))
            except Exception as error:  # build_object reports its own failures; this is a lost worker
                results.append(ObjectResult(job.spec.name, "failed", f"{type(error).__name__}: {error}", 0.0, None))
            bar.set_postfix_str(job.spec.name)
            bar.update()
    bar.close()
    return results


def _texture_source(source: str, path: str) -> Path:
    if source == "libero":
        return libero_root() / path
    if source == "pybullet":
        return pybullet_root() / path
    raise AssetBuildError(f"unknown texture source {source!r}")


def _build_textures(root: Path, max_px: int) -> list[dict]:
    """Each table texture as a manifest entry with its file's sha256 (checked on load); a file that no longer
    hashes to the last manifest's value is made again."""
    recorded = {e.get("file"): e.get("sha256") for e in _previous_manifest(root).get("textures", [])}
    entries = []
    for spec in table_textures():
        source = _texture_source(spec.source, spec.path)
        digest = hashlib.sha256(f"{PROCESSING_VERSION}:{max_px}".encode())
        _hash_files(digest, [source])
        relative = f"{TEXTURES_DIRNAME}/{spec.name}-{digest.hexdigest()[:_KEY_CHARS]}.png"
        target = root / relative
        if target.is_file() and recorded.get(relative) not in (None, file_sha256(target)):
            log.warning("table texture %s changed since it was built: it is made again", target)
            target.unlink()
        if not target.is_file():
            with Image.open(source) as opened:
                image = opened.convert("RGB")
                image.thumbnail((max_px, max_px), Image.Resampling.LANCZOS)
                with atomic_path(target) as tmp:
                    image.save(tmp, format="PNG")
        entries.append({"name": spec.name, "split": spec.split, "file": relative, "sha256": file_sha256(target)})
    return entries


def _manifest_entry(job: _Job, result: ObjectResult) -> dict:
    spec = job.spec
    entry = {
        "name": spec.name,
        "human_name": spec.human_name,
        "synonyms": list(spec.synonyms),
        "category": spec.category,
        "split": spec.split,
        "source": f"{spec.source}:{spec.path}",
        "licence": spec.licence,
        "status": result.status,
        "reason": result.reason,
        "build_seconds": round(result.seconds, 2),
        "folder": job.folder if result.status == "ok" else None,
        "extents": None,
        "hulls": None,
    }
    if result.asset is not None:
        entry["extents"] = [round(e, 4) for e in result.asset.extents]
        entry["hulls"] = len(result.asset.hulls)
    return entry


def _previous_manifest(root: Path) -> dict:
    """The last build's manifest, or {} when there is none usable (rebuilt from nothing, and rewritten)."""
    try:
        manifest = json.loads((root / MANIFEST_FILE).read_text())
    except (OSError, ValueError):
        return {}
    return manifest if manifest_problem(manifest) is None else {}


def _previous_entries(root: Path) -> list[dict]:
    objects = _previous_manifest(root).get("objects", [])
    return [e for e in objects if e["status"] != "ok" or (root / e["folder"] / CHECKSUMS_FILE).is_file()]


def _remove_unreferenced(root: Path, manifest: dict) -> None:
    """After a full build: drop folders and textures of older keys."""
    keep = {e["folder"] for e in manifest["objects"] if e["folder"]} | {t["file"] for t in manifest["textures"]}
    for sub in (OBJECTS_DIRNAME, TEXTURES_DIRNAME):
        refuse_links(root / sub)
        for path in (root / sub).glob("*") if (root / sub).is_dir() else ():
            if f"{sub}/{path.name}" not in keep and not path.name.startswith("."):
                remove_tree(path)


def build_library(
    config: LibraryConfig | None = None,
    cache: str | Path | None = None,
    progress: bool = True,
    executor: Executor | None = None,
) -> Library:
    """Builds what is missing into `<cache>/library` with `executor`'s workers (default: this process),
    writes the manifest, returns the library.

    Objects already built with the same key are reused, so a second call is a quick no-op.
    Objects that fail are logged, marked failed in the manifest and left out of the library.
    """
    config = config or default_config()
    root = library_cache(cache)
    entries = _build_objects(root, [_job(spec, config) for spec in resolve_specs(config)], config, executor, progress)
    if config.objects is not None:  # a partial build updates the library, keeps the rest
        built = {e["name"] for e in entries}
        entries = [e for e in _previous_entries(root) if e["name"] not in built] + entries
    manifest = {
        "version": MANIFEST_VERSION,
        "objects": sorted(entries, key=lambda e: e["name"]),
        "textures": _build_textures(root, config.texture_px),
    }
    _write_manifest(root, manifest)
    if config.objects is None:
        _remove_unreferenced(root, manifest)
    return load_library(cache)


def _build_objects(
    root: Path, jobs: list[_Job], config: LibraryConfig, executor: Executor | None, progress: bool
) -> list[dict]:
    """Builds the jobs not cached under `root`; the manifest entry of each job, failed ones included."""
    refuse_links(root / OBJECTS_DIRNAME, root / TEXTURES_DIRNAME)  # before anything is written into them
    remove_abandoned_tmp(root / TMP_DIRNAME)
    results = {}
    for job in jobs:
        if job.files is None:
            results[job.spec.name] = ObjectResult(job.spec.name, "failed", job.error, 0.0, None)
        elif cached := _cached(root, job):
            results[job.spec.name] = cached
    todo = [job for job in jobs if job.spec.name not in results]
    with contextlib.ExitStack() as stack:
        executor = executor or stack.enter_context(open_executor(ExecutorConfig(workers=1)))
        for result in _run_jobs(todo, config, root, executor, progress):
            results[result.name] = result
    for result in results.values():
        if result.status != "ok":
            log.warning("skipped %s: %s", result.name, result.reason)
    return [_manifest_entry(job, results[job.spec.name]) for job in jobs]


def _write_manifest(root: Path, manifest: dict) -> None:
    text = json.dumps(manifest, indent=1) + "\n"
    manifest_path = root / MANIFEST_FILE
    if not manifest_path.is_file() or manifest_path.read_text() != text:
        write_text_atomic(manifest_path, text)


def build_catalogue(
    catalogue: Catalogue,
    config: LibraryConfig | None = None,
    cache: str | Path | None = None,
    progress: bool = True,
    executor: Executor | None = None,
) -> Library:
    """Builds a user's catalogue into `<cache>/catalogues/<name>` (never the library): its objects, a manifest that
    records the catalogue's content hash, and nothing it no longer lists (pruned)."""
    config = config or default_config()
    root = catalogue_root(catalogue.name, cache)
    entries = _build_objects(root, [_job(spec, config) for spec in catalogue.specs], config, executor, progress)
    manifest = {
        "version": MANIFEST_VERSION,
        "objects": sorted(entries, key=lambda e: e["name"]),
        "textures": [],
        "catalogue": catalogue_record(catalogue),
    }
    _write_manifest(root, manifest)
    _remove_unreferenced(root, manifest)
    return load_library_at(root)


def remove_objects(names: list[str], cache: str | Path | None = None) -> list[str]:
    """Removes objects added with `--gso` from the library (manifest entry and folder); the packaged objects are
    the benchmark and stay. Returns the names removed."""
    root = library_cache(cache)
    manifest = _previous_manifest(root)
    listed = {e["name"]: e for e in manifest.get("objects", [])}
    packaged = {spec.name for spec in packaged_objects()}
    problems = [f"{n!r} is a benchmark object (objects.json): it stays" for n in names if n in packaged]
    problems += [f"no object {n!r} in {root}" for n in names if n not in packaged and n not in listed]
    if problems:
        raise UnknownObject("; ".join(problems) + "; `ocplace assets list` shows the library")
    manifest["objects"] = [e for e in manifest["objects"] if e["name"] not in names]
    _write_manifest(root, manifest)
    for name in names:
        folder = listed[name].get("folder")
        if folder:
            remove_tree(root / folder)
    return list(names)
