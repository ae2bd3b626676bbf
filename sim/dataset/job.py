"""The dataset job: resumable, atomic, parallel generation, the manifest, and verification.

    DIR/dataset.json     generator config and code version, written before any scene
    DIR/manifest.json    counts, resample statistics and the sha256 of every file, written last
    DIR/<split>/<id>/    one scene (see records.py)

Each scene is written into a temporary folder and renamed into place, so a killed run leaves no
half-written scene; a rerun skips finished scenes and makes the rest.
"""

from __future__ import annotations

import concurrent.futures
import hashlib
import json
import multiprocessing
import os
import shutil
import subprocess
from pathlib import Path

from tqdm import tqdm

import ocplace
from ocplace.errors import DatasetError
from ocplace.paths import write_text_atomic
from ocplace.sim.dataset.config import DatasetConfig
from ocplace.sim.dataset.generate import SceneGenerator, describe, level_schedule, scene_id
from ocplace.sim.dataset.records import IMAGE_FILES, SCENE_FILE, read_meta

CONFIG_FILE = "dataset.json"
MANIFEST_FILE = "manifest.json"
TMP_PREFIX = ".tmp-"


def code_version() -> str:
    """The package version plus the git commit of the source tree when there is one."""
    source = Path(ocplace.__file__).resolve().parent.parent
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=source, capture_output=True,
                                text=True, timeout=5).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        commit = ""
    return f"{ocplace.__version__}+{commit}" if commit else ocplace.__version__


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def write_scene(scene_dir: Path, files: dict[str, bytes]) -> None:
    """Writes a scene folder atomically: a temporary sibling folder renamed into place."""
    scene_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = scene_dir.parent / f"{TMP_PREFIX}{scene_dir.name}-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    for name, data in files.items():
        (tmp / name).write_bytes(data)
    try:
        os.rename(tmp, scene_dir)
    except OSError:
        shutil.rmtree(tmp, ignore_errors=True)
        if not (scene_dir / SCENE_FILE).exists():
            raise


def _claim_directory(out: Path, config: DatasetConfig) -> None:
    """Checks `out` is empty or holds this same dataset, and records the config before any work."""
    wanted = {"config": describe(config)}
    config_path = out / CONFIG_FILE
    if config_path.exists():
        try:
            existing = json.loads(config_path.read_text())
        except ValueError:
            raise DatasetError(f"{config_path} is corrupt; delete it to start this dataset afresh") from None
        if existing.get("config") != wanted["config"]:
            raise DatasetError(f"{out} holds another dataset (its {CONFIG_FILE} has a different configuration); "
                               "choose another --out folder or delete that one")
    elif out.exists() and any(p for p in out.iterdir() if not p.name.startswith(".")):
        raise DatasetError(f"{out} is not empty and holds no {CONFIG_FILE}; choose an empty or new folder")
    else:
        write_text_atomic(config_path, json.dumps(wanted | {"code_version": code_version()}, indent=2))


def _remove_leftovers(out: Path) -> None:
    for tmp in out.glob(f"*/{TMP_PREFIX}*"):
        shutil.rmtree(tmp, ignore_errors=True)


def _scene_is_complete(scene_dir: Path) -> bool:
    return all((scene_dir / name).is_file() for name in (SCENE_FILE, *IMAGE_FILES))


def verify_dataset(out: str | Path) -> list[tuple[str, str]]:
    """`(scene id or file, problem)` for every missing, corrupt or unlisted file; empty when sound."""
    out = Path(out)
    manifest_path = out / MANIFEST_FILE
    if not manifest_path.exists():
        raise DatasetError(f"{out} has no {MANIFEST_FILE}: the dataset is incomplete; rerun `ocplace generate`")
    try:
        manifest = json.loads(manifest_path.read_text())
    except ValueError:
        raise DatasetError(f"{manifest_path} is corrupt; rerun `ocplace generate` to rewrite it") from None
    problems = []
    for relative, digest in manifest["files"].items():
        path = out / relative
        scene = Path(relative).parent.name
        if not path.is_file():
            problems.append((scene, f"{relative} is missing"))
        elif _sha256(path) != digest:
            problems.append((scene, f"{relative} does not match its sha256"))
        elif path.name == SCENE_FILE:
            try:
                read_meta(path.parent)
            except DatasetError as error:
                problems.append((scene, str(error)))
    return problems


def _drop_corrupt_scenes(out: Path) -> int:
    """Deletes scenes the manifest says are damaged, so the run regenerates them."""
    if not (out / MANIFEST_FILE).exists():
        return 0
    bad = {scene for scene, _ in verify_dataset(out)}
    for scene in bad:
        split = scene.rsplit("-", 1)[0]
        shutil.rmtree(out / split / scene, ignore_errors=True)
    return len(bad)


_WORKER: dict = {}


def _init_worker(config: DatasetConfig, cache: str | None) -> None:
    import ocplace  # noqa: F401  (sets the OpenGL default in the fresh process)
    from ocplace.sim.library import load_library

    _WORKER["generator"] = SceneGenerator(load_library(cache), config)


def _make_scene(out: str, split: str, index: int, level: str) -> str:
    files = _WORKER["generator"].make(split, index, level)
    write_scene(Path(out) / split / scene_id(split, index), files)
    return scene_id(split, index)


def generate_dataset(out: str | Path, config: DatasetConfig, splits: list[str] | None = None,
                     workers: int = 1, cache: str | None = None, progress: bool = True) -> dict:
    """Generates (or completes) the dataset in `out`; returns the manifest."""
    out = Path(out)
    config.validate()
    splits = [s.name for s in config.splits] if splits is None else splits
    for name in splits:
        config.split(name)
    if workers < 1:
        raise DatasetError(f"--workers must be at least 1, got {workers}")
    out.mkdir(parents=True, exist_ok=True)
    _claim_directory(out, config)
    _remove_leftovers(out)
    regenerated = _drop_corrupt_scenes(out)
    jobs = [(name, index, level)
            for name in splits
            for index, level in enumerate(level_schedule(config.split(name), config.seed))
            if not _scene_is_complete(out / name / scene_id(name, index))]
    bar = tqdm(total=len(jobs), desc="scenes", unit="scene", disable=not progress)
    if workers == 1:
        _init_worker(config, cache)
        for job in jobs:
            _make_scene(str(out), *job)
            bar.update()
        _WORKER.pop("generator").close()
    else:
        context = multiprocessing.get_context("spawn")  # forking after JAX or EGL start-up is unsafe
        with concurrent.futures.ProcessPoolExecutor(workers, mp_context=context, initializer=_init_worker,
                                                    initargs=(config, cache)) as pool:
            futures = [pool.submit(_make_scene, str(out), *job) for job in jobs]
            for future in concurrent.futures.as_completed(futures):
                future.result()
                bar.update()
    bar.close()
    return write_manifest(out, config, regenerated)


def write_manifest(out: Path, config: DatasetConfig, regenerated: int = 0) -> dict:
    files, counts, resamples = {}, {}, {"scenes": 0, "relations": 0}
    for split in config.splits:
        for scene_dir in sorted((out / split.name).glob(f"{split.name}-*")):
            meta = read_meta(scene_dir)
            level_counts = counts.setdefault(split.name, {})
            level_counts[meta["level"]] = level_counts.get(meta["level"], 0) + 1
            for key in resamples:
                resamples[key] += meta["resamples"][key]
            for name in (SCENE_FILE, *IMAGE_FILES):
                files[f"{split.name}/{scene_dir.name}/{name}"] = _sha256(scene_dir / name)
    manifest = {
        "config": describe(config),
        "code_version": code_version(),
        "counts": counts,
        "statistics": {"resamples": resamples, "regenerated_corrupt_scenes": regenerated,
                       "bytes": int(sum((out / f).stat().st_size for f in files))},
        "files": files,
    }
    write_text_atomic(out / MANIFEST_FILE, json.dumps(manifest, indent=1, sort_keys=True))
    return manifest


def dataset_hash(out: str | Path) -> str:
    """A short hash of the manifest's file list: changes whenever any scene file changes."""
    manifest = json.loads((Path(out) / MANIFEST_FILE).read_text())
    digest = hashlib.sha256(json.dumps(manifest["files"], sort_keys=True).encode()).hexdigest()
    return digest[:16]


def scene_dirs(out: str | Path, split: str) -> list[Path]:
    dirs = sorted((Path(out) / split).glob(f"{split}-*"))
    if not dirs:
        raise DatasetError(f"{out} has no scenes of split {split!r}; generate them with "
                           f"`ocplace generate --out {out} --split {split}`")
    return dirs

