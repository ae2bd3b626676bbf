"""The dataset job: resumable, atomic, parallel generation, the manifest, and verification.

    DIR/dataset.json     generator config and code version, written before any scene
    DIR/manifest.json    counts, resample statistics and the sha256 of every file, written last
    DIR/<split>/<id>/    one scene (see records.py)

Each scene is written into a temporary folder and renamed into place, so a killed run leaves no
half-written scene; a rerun skips finished scenes and makes the rest.

The manifest is what a dataset is: readers take the scenes it lists, never whatever folders exist,
and every entry is checked to name a scene file inside DIR before anything is read or deleted.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import shutil
import signal
import socket
import subprocess
from collections.abc import Mapping
from pathlib import Path

import ocplace
from ocplace.errors import DatasetConfigError, DatasetError
from ocplace.paths import disk_full_is_typed, file_sha256, inside, read_json_bounded, write_text_atomic
from ocplace.runtime import Executor, ExecutorConfig, Task, map_tasks, open_executor
from ocplace.runtime.progress import progress_bar
from ocplace.sim.dataset.config import DatasetConfig, generate_advice
from ocplace.sim.dataset.generate import SceneGenerator, describe, level_schedule, scene_id
from ocplace.sim.dataset.records import IMAGE_FILES, SCENE_FILE, SceneInfo, SceneRecord, read_meta, read_scene
from ocplace.vocabulary import DEV_SPLITS, TEST_SUBSETS

CONFIG_FILE = "dataset.json"
MANIFEST_FILE = "manifest.json"
TMP_PREFIX = ".tmp-"
SCENE_FILES = (SCENE_FILE, *IMAGE_FILES)
SCENES_PER_TASK = 16  # about 2 s of work per task on this project's CPUs (a scene takes about 0.12 s)
# Set to N, the process writing scenes SIGKILLs itself right after committing its Nth scene, so the
# resume tests crash a run at a known point instead of racing a kill against the generator. Unset: off.
DIE_AFTER_SCENES_ENV = "OCPLACE_TEST_DIE_AFTER_SCENES"
# With it set to a file path as well, only the first process to create that file dies: one lost worker
# in a whole run, which the Ray executor must retry without losing or duplicating a scene.
DIE_ONCE_MARKER_ENV = "OCPLACE_TEST_DIE_ONCE_MARKER"


def code_version() -> str:
    """The package version plus the git commit of the source tree when there is one."""
    source = Path(ocplace.__file__).resolve().parent.parent
    try:
        commit = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=source, capture_output=True, text=True, timeout=5
        ).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        commit = ""
    return f"{ocplace.__version__}+{commit}" if commit else ocplace.__version__


def write_scene(scene_dir: Path, files: dict[str, bytes]) -> None:
    """Writes a scene folder atomically: a temporary sibling folder renamed into place. A full disk is an
    OutputError naming the scene, and its temporary folder is removed."""
    tmp = scene_dir.parent / f"{TMP_PREFIX}{scene_dir.name}-{socket.gethostname()}-{os.getpid()}"
    with disk_full_is_typed(scene_dir):
        scene_dir.parent.mkdir(parents=True, exist_ok=True)
        shutil.rmtree(tmp, ignore_errors=True)
        try:
            tmp.mkdir()
            for name, data in files.items():
                (tmp / name).write_bytes(data)
            os.rename(tmp, scene_dir)
        except OSError:
            shutil.rmtree(tmp, ignore_errors=True)
            if not (scene_dir / SCENE_FILE).exists():  # else another worker wrote it first
                raise


def _claim_directory(out: Path, config: DatasetConfig) -> None:
    """Checks `out` is empty or holds this same dataset, and records the config before any work."""
    wanted = {"config": describe(config)}
    config_path = out / CONFIG_FILE
    if config_path.exists():
        try:
            existing = json.loads(config_path.read_text())
        except ValueError:
            existing = None
        if not isinstance(existing, dict):
            raise DatasetError(f"{config_path} is corrupt; delete it to start this dataset afresh")
        if existing.get("config") != wanted["config"]:
            raise DatasetError(
                f"{out} holds another dataset (its {CONFIG_FILE} has a different configuration); "
                "choose another --out folder or delete that one"
            )
    elif out.exists() and any(p for p in out.iterdir() if not p.name.startswith(".")):
        raise DatasetError(f"{out} is not empty and holds no {CONFIG_FILE}; choose an empty or new folder")
    else:
        write_text_atomic(config_path, json.dumps(wanted | {"code_version": code_version()}, indent=2))


def _inside(out: Path, relative: str) -> Path:
    """A folder of this dataset; DatasetError if a symlink leads it out of `out`."""
    try:
        return inside(out, relative)
    except ValueError as error:
        raise DatasetError(
            f"{error}; a dataset keeps all its scenes inside its folder: remove that symlink "
            f"(or move its target into {out}) and rerun"
        ) from None


def _listed_path(out: Path, relative: str) -> Path:
    """The scene file a manifest entry names; DatasetError unless it is `<split>/<split>-<n>/<file>` in `out`."""
    parts = relative.split("/") if isinstance(relative, str) else []
    if len(parts) != 3 or parts[2] not in SCENE_FILES or not parts[1].startswith(f"{parts[0]}-"):
        problem = f"{relative!r} is not <split>/<scene id>/<scene file>"
    else:
        try:
            return inside(out, relative)
        except ValueError as error:
            problem = str(error)
    raise DatasetError(
        f"corrupt dataset: an entry of {out / MANIFEST_FILE} is unsafe: {problem}. ocplace never "
        f"writes such an entry, so nothing was read or deleted; remove any symlink out of {out}, "
        f"delete the manifest and rerun `ocplace generate --out {out}` with the same options"
    )


def read_manifest(out: str | Path) -> dict:
    """The manifest of `out`, with every entry checked before any is used."""
    out = Path(out)
    path = out / MANIFEST_FILE
    if not path.exists():
        raise DatasetError(f"{out} has no {MANIFEST_FILE}: the dataset is incomplete; rerun `ocplace generate`")
    try:
        manifest = json.loads(path.read_text())
    except ValueError:
        manifest = None
    files = manifest.get("files") if isinstance(manifest, dict) else None
    if not isinstance(files, dict) or not all(isinstance(digest, str) for digest in files.values()):
        raise DatasetError(
            f"corrupt dataset: {path} is not a manifest written by `ocplace generate`; delete it and "
            f"rerun `ocplace generate --out {out}` with the same options to rewrite it"
        )
    for relative in files:
        _listed_path(out, relative)
    return manifest


def _remove_leftovers(out: Path, config: DatasetConfig) -> None:
    for split in config.splits:
        for tmp in _inside(out, split.name).glob(f"{TMP_PREFIX}*"):
            shutil.rmtree(tmp, ignore_errors=True)


def _scene_dir(out: Path, split: str, index: int) -> Path:
    return _inside(out, f"{split}/{scene_id(split, index)}")


def _scene_is_complete(scene_dir: Path) -> bool:
    return all((scene_dir / name).is_file() for name in SCENE_FILES)


def _damaged_files(out: Path, manifest: dict) -> list[tuple[str, str]]:
    """`(manifest entry, problem)` for every listed file that is missing, corrupt or off-schema."""
    problems = []
    for relative, digest in manifest["files"].items():
        path = _listed_path(out, relative)
        if not path.is_file():
            problems.append((relative, f"{relative} is missing"))
        elif file_sha256(path) != digest:
            problems.append((relative, f"{relative} does not match its sha256"))
        elif path.name == SCENE_FILE:
            try:
                read_meta(path.parent)
            except DatasetError as error:
                problems.append((relative, str(error)))
    return problems


def _unlisted(out: Path, manifest: dict) -> list[tuple[str, str]]:
    """`(path, problem)` for every folder or file in `out` that the manifest does not list.

    Hidden names are left out: leftovers of a killed run, which the next run removes. Symlinks are
    reported, not followed.
    """
    files = set(manifest["files"]) | {CONFIG_FILE, MANIFEST_FILE}
    folders = {parent.as_posix() for relative in files for parent in Path(relative).parents} - {"."}
    problems = []
    for top, dirnames, filenames in os.walk(out):
        base = Path(top).relative_to(out)
        for name in sorted(dirnames + filenames):
            relative = (base / name).as_posix()
            if not name.startswith(".") and relative not in files and relative not in folders:
                problems.append(
                    (
                        relative,
                        f"{relative} is not in the manifest, so nothing reads it; "
                        "delete it or move it out of the dataset",
                    )
                )
        dirnames[:] = sorted(name for name in dirnames if (base / name).as_posix() in folders)
    return problems


def verify_dataset(out: str | Path) -> list[tuple[str, str]]:
    """`(scene id or file, problem)` for every missing, corrupt or unlisted file; empty when sound."""
    out = Path(out)
    manifest = read_manifest(out)
    damaged = [(relative.split("/")[1], problem) for relative, problem in _damaged_files(out, manifest)]
    return damaged + _unlisted(out, manifest)


def _drop_damaged_scenes(out: Path, manifest: dict | None) -> int:
    """Deletes the listed scenes that are damaged, so the run makes them again; never an unlisted file."""
    if manifest is None:
        return 0
    bad = {_listed_path(out, relative).parent for relative, _ in _damaged_files(out, manifest)}
    for scene_dir in bad:
        shutil.rmtree(scene_dir, ignore_errors=True)
    return len(bad)


# Per process: the scene generator of the dataset being made (building one loads the library and
# compiles the MuJoCo arena, so a worker keeps it across its tasks), and the scenes it wrote.
_WORKER: dict = {}


def _generator(config: DatasetConfig, cache: str | None) -> SceneGenerator:
    key = (json.dumps(describe(config), sort_keys=True), cache)
    if _WORKER.get("key") != key:
        import ocplace  # noqa: F401  (sets the OpenGL default in a fresh process)

        _close_generator()
        _WORKER.update(key=key, generator=SceneGenerator(dataset_library(config, cache), config), written=0)
    return _WORKER["generator"]


def dataset_library(config: DatasetConfig, cache: str | None = None):
    """The library a dataset's scenes are made (and physically checked) with: the benchmark's, or for a dataset of
    a user's catalogue, that catalogue's objects (checked to be the content it recorded) and its distractors."""
    from ocplace.sim.library import load_library
    from ocplace.sim.library.catalogue_library import subset_library

    if config.catalogue is None:
        return load_library(cache)
    return subset_library(config.catalogue, config.distractors, cache)


def library_of_dataset(out: str | Path, cache: str | None = None):
    """`dataset_library` of the dataset in `out`, from the configuration its dataset.json records."""
    path = Path(out) / CONFIG_FILE
    try:
        described = read_json_bounded(path)["config"]
    except (OSError, ValueError, KeyError, TypeError) as error:  # FileRefused is a ValueError
        raise DatasetError(
            f"cannot read {path} ({error}); the dataset is incomplete: rerun `ocplace generate`"
        ) from None
    catalogue = described.get("catalogue") if isinstance(described, dict) else None
    config = DatasetConfig(splits=(), catalogue=catalogue, distractors=described.get("distractors"))
    return dataset_library(config, cache)


def _check_own_pools(config: DatasetConfig, library) -> None:
    """Each subset of a catalogue's dataset has the objects a scene needs: DatasetConfigError before any work."""
    from ocplace.sim.scene import NUM_SCENE_OBJECTS

    problems = []
    for split in config.splits:
        own = library.names(split.name)
        needed = 3 if config.distractors else NUM_SCENE_OBJECTS + 1
        if len(own) < needed:
            problems.append(f"subset {split.name!r} has {len(own)} objects; its scenes need {needed}")
    if problems:
        raise DatasetConfigError(
            "; ".join(problems) + f": {NUM_SCENE_OBJECTS} on the table and one held, or with `--distractors "
            "unseen` (benchmark objects never referred to) one held and two on the table. Add objects to the catalogue"
        )


def _close_generator() -> None:
    if "generator" in _WORKER:
        _WORKER.pop("generator").close()
        _WORKER.clear()


def _die_if_asked() -> None:
    """The test hook: SIGKILL after this process's Nth committed scene (once in all, given a marker file)."""
    if _WORKER["written"] != int(os.environ.get(DIE_AFTER_SCENES_ENV, "0")):
        return
    marker = os.environ.get(DIE_ONCE_MARKER_ENV)
    if marker:
        try:
            os.close(os.open(marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY))
        except FileExistsError:
            return
    os.kill(os.getpid(), signal.SIGKILL)


def _make_scenes(out: str, config: DatasetConfig, cache: str | None, scenes: tuple[tuple[str, int, str], ...]) -> int:
    """Makes and writes `(split, index, level)` scenes one after another; returns how many."""
    for split, index, level in scenes:
        if _scene_is_complete(Path(out) / split / scene_id(split, index)):
            continue  # written before this task was retried
        files = _generator(config, cache).make(split, index, level)
        write_scene(Path(out) / split / scene_id(split, index), files)
        _WORKER["written"] += 1
        _die_if_asked()
    return len(scenes)


def scenes_per_task(num_scenes: int, workers: int) -> int:
    """Scenes a task makes: up to SCENES_PER_TASK, so that a scheduler's cost per task (a round trip to a
    Ray raylet on another node) is paid per second of work, not per scene; but at least four tasks per
    worker, so that workers finish together and a retried task redoes little."""
    return max(1, min(SCENES_PER_TASK, num_scenes // (4 * workers)))


def generate_dataset(
    out: str | Path,
    config: DatasetConfig,
    splits: list[str] | None = None,
    executor: Executor | None = None,
    cache: str | None = None,
    progress: bool = True,
    test_dataset: str | Path | None = None,
) -> dict:
    """Generates (or completes) the dataset in `out` with `executor`'s workers (default: this process);
    returns the manifest. Every worker writes its scenes into `out` itself, so they must all see it. A dev
    scene that is a test scene of `out` (or of `test_dataset`, a dataset folder) is a DatasetError."""
    out = Path(out)
    config.validate()
    tests = read_manifest(test_dataset) if test_dataset is not None else None  # checked before any scene
    if config.catalogue is not None:
        _check_own_pools(config, dataset_library(config, cache))
    splits = [s.name for s in config.splits] if splits is None else splits
    for name in splits:
        config.split(name)
    out.mkdir(parents=True, exist_ok=True)
    _claim_directory(out, config)
    # Read (and so checked) before anything is removed: a crafted manifest must not steer a deletion.
    manifest = read_manifest(out) if (out / MANIFEST_FILE).exists() else None
    _remove_leftovers(out, config)
    regenerated = _drop_damaged_scenes(out, manifest)
    wanted = [
        (name, index, level)
        for name in splits
        for index, level in enumerate(level_schedule(config.split(name), config.seed))
        if not _scene_is_complete(_scene_dir(out, name, index))
    ]
    with contextlib.ExitStack() as stack:
        stack.callback(_close_generator)  # the one this process made, when tasks ran here
        if executor is None:
            executor = stack.enter_context(open_executor(ExecutorConfig(workers=1)))
        size = scenes_per_task(len(wanted), executor.capacity)
        tasks = [
            Task(_make_scenes, (str(out), config, cache, tuple(wanted[i : i + size])))
            for i in range(0, len(wanted), size)
        ]
        with progress_bar(total=len(wanted), desc="scenes", unit="scene", enabled=progress) as bar:
            for _, made in map_tasks(executor, tasks):
                bar.update(made)
    manifest = write_manifest(out, config, regenerated)
    check_dev_scenes(out, manifest, tests)
    return manifest


def check_dev_scenes(out: Path, manifest: Mapping, tests: Mapping | None = None) -> None:
    """Raises DatasetError when a dev scene of `manifest` is a test scene of it or of `tests` (another dataset's
    manifest): the same image."""
    coinciding = coinciding_scenes(manifest, tests)
    if coinciding:
        dev, test = coinciding[0]
        raise DatasetError(
            f"{out}: {len(coinciding)} dev scene(s) are test scenes (the same image), e.g. {dev} is {test}; a dev "
            f"split never holds a test scene. Delete {out / dev.split('/')[0]} and generate it again"
        )


def coinciding_scenes(manifest: Mapping, tests: Mapping | None = None) -> list[tuple[str, str]]:
    """`(dev scene, test scene)` folders whose images are the same file (sha256): the dev scenes of `manifest`
    against the test scenes of `tests` (default: of `manifest` itself)."""
    test_images = {
        digest: name.rpartition("/")[0]
        for name, digest in (tests or manifest)["files"].items()
        if name.endswith("/rgb.png") and name.split("/")[0] in TEST_SUBSETS
    }
    return [
        (name.rpartition("/")[0], test_images[digest])
        for name, digest in sorted(manifest["files"].items())
        if name.endswith("/rgb.png") and name.split("/")[0] in DEV_SPLITS and digest in test_images
    ]


def write_manifest(out: Path, config: DatasetConfig, regenerated: int = 0) -> dict:
    """Lists the config's scenes that exist; a folder the config does not name stays unlisted, so unread."""
    files: dict[str, str] = {}
    counts: dict[str, dict[str, int]] = {}
    resamples = {"scenes": 0, "relations": 0}
    for split in config.splits:
        for index in range(split.num_scenes):
            scene_dir = _scene_dir(out, split.name, index)
            if not scene_dir.exists():
                continue
            scene = SceneInfo(read_meta(scene_dir))
            level_counts = counts.setdefault(split.name, {})
            level_counts[scene.level] = level_counts.get(scene.level, 0) + 1
            resamples["scenes"] += scene.resamples.scenes
            resamples["relations"] += scene.resamples.relations
            for name in SCENE_FILES:
                files[f"{split.name}/{scene_dir.name}/{name}"] = file_sha256(scene_dir / name)
    manifest = {
        "config": describe(config),
        "code_version": code_version(),
        "counts": counts,
        "statistics": {
            "resamples": resamples,
            "regenerated_corrupt_scenes": regenerated,
            "bytes": int(sum((out / f).stat().st_size for f in files)),
        },
        "files": files,
    }
    write_text_atomic(out / MANIFEST_FILE, json.dumps(manifest, indent=1, sort_keys=True))
    return manifest


@dataclasses.dataclass(frozen=True)
class ListedScene:
    """A scene folder that the manifest lists, with the sha256 it lists for each file of the scene.

    Reading through it hashes every file as it is read: a scene edited after generation is a
    DatasetError naming it, never a scene read (and scored) as the dataset's.
    """

    dir: Path
    digests: Mapping[str, str]  # file name -> sha256

    @property
    def name(self) -> str:
        return self.dir.name

    def read(self) -> SceneRecord:
        return read_scene(self.dir, self.digests)

    def info(self) -> SceneInfo:
        return SceneInfo(read_meta(self.dir, self.digests))


def listed_scenes(out: str | Path, split: str) -> list[ListedScene]:
    """The scenes of `split` that the manifest lists, in id order: what `verify` checked."""
    out = Path(out)
    digests: dict[Path, dict[str, str]] = {}
    for relative, digest in read_manifest(out)["files"].items():  # read_manifest checked every entry
        if relative.startswith(f"{split}/"):
            path = out / relative
            digests.setdefault(path.parent, {})[path.name] = digest
    if not digests:
        raise DatasetError(f"{out} has no scenes of split {split!r}; {generate_advice(out, split)}")
    return [ListedScene(scene_dir, digests[scene_dir]) for scene_dir in sorted(digests)]


def dataset_scene(dataset_dir: str | Path, scene_id: str) -> SceneRecord:
    """The scene `scene_id` (e.g. `seen-00003`; its split is the part before the last dash) of a dataset,
    read through its manifest; DatasetError naming the scenes there are when it is not one of them."""
    split = scene_id.rpartition("-")[0]
    scenes = listed_scenes(dataset_dir, split) if split else []
    for scene in scenes:
        if scene.name == scene_id:
            return scene.read()
    named = f"{scenes[0].name} to {scenes[-1].name}" if scenes else "ids such as seen-00003"
    raise DatasetError(f"no scene {scene_id!r} in {dataset_dir}; its scenes are named {named}")


def scene_dirs(out: str | Path, split: str) -> list[Path]:
    """The folders of `listed_scenes`, for code that names or counts scenes; readers use `listed_scenes`."""
    return [scene.dir for scene in listed_scenes(out, split)]
