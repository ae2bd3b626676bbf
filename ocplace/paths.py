"""Where ocplace keeps what it builds: the cache root, the files of a run directory, atomic file writes,
and names read from files."""

from __future__ import annotations

import contextlib
import errno
import hashlib
import json
import os
import shutil
import stat
import tempfile
from pathlib import Path

from ocplace.errors import CacheError, FileRefused, OutputError, TrainingError

RUN_FILE = "run.json"  # a run's identity: a rerun with other contents is refused, a rerun with the same resumes
WEIGHTS_FILE = "weights.safetensors"  # what a run ends with; its presence marks the run finished
# What older versions called those files: a run holding one is refused, never read with mixed names.
OLD_RUN_FILES = ("config.json", "adapters.safetensors", "model.safetensors")

_DISK_FULL = (errno.ENOSPC, errno.EDQUOT)


def cache_dir() -> Path:
    """The cache root: `$OCPLACE_CACHE`, else the platform's user cache (`$XDG_CACHE_HOME/ocplace`, by default
    `~/.cache/ocplace` on Linux)."""
    import platformdirs

    root = os.environ.get("OCPLACE_CACHE") or platformdirs.user_cache_dir("ocplace", appauthor=False)
    return Path(root).expanduser()


# The cache's folders, each named here once (docs/architecture.md, "Cache"). Their names are what caches on
# disk already use: renaming one would orphan every file in it.


def library_cache(cache: str | os.PathLike | None = None) -> Path:
    """The object library (meshes, textures, manifest), under `cache` when given, else under `cache_dir()`."""
    return Path(cache if cache is not None else cache_dir()).expanduser() / "library"


def catalogues_cache(cache: str | os.PathLike | None = None) -> Path:
    """Objects of users' own catalogues (`ocplace assets build --catalogue`), one folder per catalogue, apart from
    the library so that no benchmark pool ever sees them."""
    return Path(cache if cache is not None else cache_dir()).expanduser() / "catalogues"


def sources_cache() -> Path:
    return cache_dir() / "sources"  # asset packages fetched for the library (the robosuite wheel, unpacked)


def features_cache() -> Path:
    return cache_dir() / "features"  # backbone features of dataset splits, and no_llm's sentence tokens


def baselines_cache() -> Path:
    return cache_dir() / "baselines"  # the baselines' inputs: grid cell features, CLIPort data, test cells


def scratch_cache() -> Path:
    return cache_dir() / "scratch"  # no_pretrain's decoded training images and phrase embeddings


def backbones_cache() -> Path:
    return cache_dir() / "backbones"  # pretrained offline backbones, one folder each, and their seeds' renders


def weights_cache() -> Path:
    return cache_dir() / "weights"  # ImageNet EfficientNet weights, converted from the pip package's file


def primitives_cache() -> Path:
    return cache_dir() / "primitives"  # generated primitive meshes of the pretraining arenas


def corpus_cache() -> Path:
    return cache_dir() / "corpus"  # the pretraining corpus: catalogue models converted for the arena


def compiled_cache() -> Path:
    return cache_dir() / "compiled"  # JAX's persistent compilation cache, one folder per CPU type and width


def processes_cache() -> Path:
    return cache_dir() / "processes"  # notes of running policy processes, for reaping what a killed command left


def llm_cache(subdir: str) -> Path:
    return cache_dir() / subdir  # the LLM parser's answers; `subdir` is `LLMConfig.cache_subdir` ("parser")


def inside(root: str | os.PathLike, relative: str) -> Path:
    """`root / relative`, or ValueError unless it names something strictly inside `root`.

    For names read from a file we did not just write (a manifest, a results file): refuses an
    absolute path, a `..` segment, an empty name, the root itself and a symlink that leads out of
    `root`, so that no such file can make us read, write or delete elsewhere.
    """
    if not isinstance(relative, str) or relative in ("", "."):
        raise ValueError(f"{relative!r} is not a file name")
    if Path(relative).is_absolute() or ".." in Path(relative).parts:
        raise ValueError(f"{relative!r} leads out of {root}")
    path = Path(root) / relative
    real_root = os.path.join(os.path.realpath(root), "")  # strings: Path.resolve and .parents are 3x slower
    if not os.path.realpath(path).startswith(real_root):
        raise ValueError(f"{relative!r} is {root} itself or a symlink that leads out of it")
    return path


def refuse_old_run(run_dir: str | os.PathLike, how_to_train: str) -> None:
    """Raises TrainingError when `run_dir` holds a file under a name from `OLD_RUN_FILES`."""
    run_dir = Path(run_dir)
    old = [name for name in OLD_RUN_FILES if (run_dir / name).is_file()]
    if old:
        raise TrainingError(
            f"{run_dir} is a run written by an older ocplace (it holds {', '.join(old)}; a run now keeps "
            f"{RUN_FILE} and {WEIGHTS_FILE}): delete it, then {how_to_train}"
        )


# Caps on the files a folder, dataset or cache holds, checked before a byte is read (docs/reliability.md): no such
# file that ocplace writes comes near them.
MAX_JSON_BYTES = 64 << 20  # a results file of paper scale is about 40 MB
MAX_CONFIG_BYTES = 1 << 20  # a config.json, run.json, catalogue: a few kilobytes
MAX_JSON_DEPTH = 32  # ocplace's own JSON nests at most 8 deep
MAX_WEIGHTS_BYTES = 8 << 30


def regular_file(path: str | os.PathLike, max_bytes: int) -> int:
    """The size of `path` when it is a regular file (after symlinks) of at most `max_bytes`; else FileRefused. A
    FIFO, device or socket is refused before it is opened: reading one would block or never end."""
    try:
        info = os.stat(path)
    except FileNotFoundError:
        raise
    except OSError as error:  # a symlink loop, a name too long
        raise FileRefused(f"{path} cannot be read: {error}") from None
    if not stat.S_ISREG(info.st_mode):
        raise FileRefused(f"{path} is not a regular file (a FIFO, device or socket), so it is not read")
    if info.st_size > max_bytes:
        raise FileRefused(f"{path} is {info.st_size:,} bytes, more than such a file may be ({max_bytes:,})")
    return info.st_size


def read_bytes_bounded(path: str | os.PathLike, max_bytes: int) -> bytes:
    """The bytes of a regular file of at most `max_bytes` (checked on the open file too: it may be swapped)."""
    regular_file(path, max_bytes)
    descriptor = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    with os.fdopen(descriptor, "rb") as handle:
        if not stat.S_ISREG(os.fstat(handle.fileno()).st_mode):
            raise FileRefused(f"{path} is not a regular file (a FIFO, device or socket), so it is not read")
        data = handle.read(max_bytes + 1)
    if len(data) > max_bytes:
        raise FileRefused(f"{path} grew past {max_bytes:,} bytes while it was read")
    return data


def read_json_bounded(path: str | os.PathLike, max_bytes: int = MAX_CONFIG_BYTES, max_depth: int = MAX_JSON_DEPTH):
    """The JSON value in `path`, read with `read_bytes_bounded`; ValueError when it is not JSON, FileRefused when it
    nests deeper than `max_depth`."""
    text = read_bytes_bounded(path, max_bytes).decode("utf-8")
    try:
        value = json.loads(text)
    except RecursionError:
        raise FileRefused(f"{path} nests its JSON deeper than {max_depth} levels") from None
    if json_depth(value) > max_depth:
        raise FileRefused(f"{path} nests its JSON deeper than {max_depth} levels")
    return value


def json_depth(value) -> int:
    """How deep `value` (decoded JSON) nests: 0 for a scalar; iterative, so no depth can overflow the stack."""
    deepest, stack = 0, [(value, 0)]
    while stack:
        item, depth = stack.pop()
        deepest = max(deepest, depth)
        children = item.values() if isinstance(item, dict) else item if isinstance(item, list) else ()
        stack.extend((child, depth + 1) for child in children)
    return deepest


def read_run_file(run_dir: str | os.PathLike) -> dict:
    """The metadata in `run_dir/RUN_FILE`; TrainingError when it is not a JSON object (cut short by a crash of
    an older ocplace, edited, damaged). FileNotFoundError when there is none."""
    path = Path(run_dir) / RUN_FILE
    try:
        meta = read_json_bounded(path)
    except ValueError:  # not JSON, or refused (FileRefused is one)
        meta = None
    if not isinstance(meta, dict):
        raise TrainingError(
            f"{path} is truncated or damaged (not a JSON object), so the run cannot be checked or resumed: delete "
            f"{run_dir} to train it again from the start, or restore that file"
        )
    return meta


def trained_weights(run_dir: str | os.PathLike, what: str, how_to_train: str) -> Path:
    """`run_dir/WEIGHTS_FILE`, the final `what` of a finished run; TrainingError when missing or from an older run."""
    refuse_old_run(run_dir, how_to_train)
    path = Path(run_dir) / WEIGHTS_FILE
    if not path.is_file():
        raise TrainingError(f"no trained {what} at {path}; {how_to_train}")
    return path


@contextlib.contextmanager
def file_lock(target: str | os.PathLike):
    """Holds an exclusive lock on `.<name>.lock` beside `target` (blocking), for work that concurrent
    processes on any node of a shared filesystem must not do twice at once (flock: advisory, so only
    code that takes the lock waits for it)."""
    import fcntl

    target = Path(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    lock = target.with_name(f".{target.name}.lock")
    try:  # O_NOFOLLOW: a link planted at the lock's name must not make us create its target
        descriptor = os.open(lock, os.O_WRONLY | os.O_CREAT | os.O_APPEND | os.O_NOFOLLOW, 0o644)
    except OSError as error:
        if error.errno != errno.ELOOP:
            raise
        raise CacheError(_link_message(lock)) from None
    with os.fdopen(descriptor, "a") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def _link_message(path: Path) -> str:
    return (
        f"{path} is a symbolic link (to {os.path.realpath(path)}); ocplace deletes and creates files inside its "
        f"cache folders, so it never follows one there: remove the link (`rm {path}`) and rerun"
    )


def refuse_links(*folders: str | os.PathLike) -> None:
    """CacheError when one of `folders` (cache folders whose entries ocplace sweeps: `tmp`, `models`, `objects`)
    is a symbolic link. The cache root and its top folders (`library`, `corpus`) may be links (another disk,
    a cache shared with another): what they hold is ocplace's; a swept folder that leads elsewhere is not."""
    for folder in folders:
        if os.path.islink(folder):
            raise CacheError(_link_message(Path(folder)))


def remove_tree(path: Path) -> None:
    """Removes `path`: a folder with what it holds, a file, or a symbolic link (the link only, never its target)."""
    if path.is_symlink() or not path.is_dir():
        path.unlink(missing_ok=True)
    else:
        shutil.rmtree(path, ignore_errors=True)


def unwritable(error: OSError, target: str | os.PathLike, then: str) -> OutputError | None:
    """The OutputError for a write into `target` that failed for the machine's reasons (a full disk, a
    read-only file system), ending with `then` ("or write the output elsewhere"); None for any other OSError
    (one about the input)."""
    if error.errno in _DISK_FULL:
        return OutputError(f"cannot write {target}: the disk is full ({error.strerror}); free some space there {then}")
    if error.errno == errno.EROFS:
        return OutputError(
            f"cannot write {target}: its file system is read-only ({error.strerror}); make it writable {then}"
        )
    return None


@contextlib.contextmanager
def disk_full_is_typed(target: str | os.PathLike):
    """Turns a full disk (ENOSPC, EDQUOT) while writing `target` into an OutputError naming it."""
    try:
        yield
    except OSError as error:
        typed = unwritable(error, target, "or write the output elsewhere") if error.errno in _DISK_FULL else None
        if typed is not None:
            raise typed from error
        raise


@contextlib.contextmanager
def atomic_path(target: str | os.PathLike):
    """Yields a temporary path beside `target`; renames it onto `target` only on success.

    A crash or kill leaves at most a stray `*.tmp*` file, never a half-written `target`; a full disk
    is an OutputError naming `target`.
    """
    target = Path(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = None
    try:
        with disk_full_is_typed(target):
            fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
            os.close(fd)
            yield Path(tmp)
            honour_umask(tmp)
            os.replace(tmp, target)
    finally:
        if tmp is not None:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp)


def current_umask() -> int:
    """The process's umask, read without changing it (`os.umask` can only set it, and another thread could create
    a file in between); Linux says it in /proc/self/status."""
    with contextlib.suppress(OSError, ValueError, StopIteration):
        status = Path("/proc/self/status").read_text().splitlines()
        return int(next(line for line in status if line.startswith("Umask:")).split()[1], 8)
    return 0o022


def honour_umask(path: str | os.PathLike) -> None:
    """Gives a file or folder made by `tempfile` (always 0600 / 0700) the mode a plain `open` or `mkdir` would have
    had: 0644 / 0755 under the usual umask 022, so that lab members can read each other's outputs."""
    default = 0o777 if os.path.isdir(path) else 0o666
    os.chmod(path, default & ~current_umask())


def check_writable(target: str | os.PathLike, as_folder: bool = False) -> None:
    """Raises OutputError unless `target` (a file or folder to create or replace; with `as_folder`, a
    folder to create or write into) can be written.

    Commands call it before any expensive work, so that a bad `--out` fails at once and not after
    minutes of computing: every existing ancestor must be a folder and the nearest one writable, and
    no symlink on the way may point at nothing (creating the folder would fail on it). Nothing is
    written to find out (a probe file would change the folder's mtime).
    """
    target = Path(target)
    if as_folder and target.exists() and not target.is_dir():
        raise OutputError(f"cannot write into {target}: it is a file, not a folder; choose a folder")
    nearest = target
    while not nearest.exists() and nearest != nearest.parent:
        if nearest.is_symlink():
            raise OutputError(
                f"cannot write {target}: {nearest} is a symlink to {os.readlink(nearest)}, which does not exist; "
                "create what it points to, remove the symlink, or choose another output path"
            )
        nearest = nearest.parent
    folder = target.parent if nearest == target and not target.is_dir() else nearest  # an existing file is replaced
    if not folder.is_dir():
        raise OutputError(f"cannot write {target}: {folder} is a file, not a folder; choose an output path in a folder")
    # os.access knows permissions (and that root passes them) but not read-only mounts: ask statvfs too.
    if not os.access(folder, os.W_OK | os.X_OK) or os.statvfs(folder).f_flag & os.ST_RDONLY:
        raise OutputError(
            f"cannot write {target}: {folder} is not writable (read-only folder or file system); "
            "choose an output path in a folder you can write"
        )


def write_bytes_atomic(target: str | os.PathLike, data: bytes) -> None:
    with atomic_path(target) as tmp:
        tmp.write_bytes(data)


def write_text_atomic(target: str | os.PathLike, text: str) -> None:
    write_bytes_atomic(target, text.encode("utf-8"))


# What Linux takes: a longer path or name fails every call with ENAMETOOLONG, a NUL byte every call with ValueError.
MAX_PATH_CHARS, MAX_NAME_BYTES = 4095, 255


def path_problem(text: str) -> str | None:
    """Why `text`, read from a file we did not just write, can name no file here (a NUL byte, a path or a name
    longer than the system takes); None when it can."""
    if "\x00" in text:
        return "it holds a NUL byte"
    if len(text.encode("utf-8", "surrogateescape")) > MAX_PATH_CHARS:
        return f"it is longer than the {MAX_PATH_CHARS:,} bytes a path may be"
    if any(len(part.encode("utf-8", "surrogateescape")) > MAX_NAME_BYTES for part in text.split("/")):
        return f"a name in it is longer than the {MAX_NAME_BYTES} bytes a file name may be"
    return None


def pid_alive(pid: int) -> bool:
    """Whether a process with this pid runs (on this machine, in this pid namespace)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def remove_abandoned_tmp(tmp_root: Path) -> None:
    """Removes the temp folders (`<name>.<pid>.<random>`) of builds that died; live builds keep theirs.
    CacheError when `tmp_root` is a symbolic link (`refuse_links`)."""
    refuse_links(tmp_root)
    if not tmp_root.is_dir():
        return
    for path in tmp_root.iterdir():
        parts = path.name.split(".")
        pid = int(parts[-2]) if len(parts) >= 3 and parts[-2].isdigit() else None
        if pid is None or not pid_alive(pid):
            remove_tree(path)


def file_sha256(path: str | os.PathLike) -> str:
    """The sha256 of a file's bytes, read in 1 MiB blocks (catalogues and weights run to 100 MB)."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()
