"""Where ocplace keeps what it builds: the cache root and atomic file writes."""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path


def cache_dir() -> Path:
    """The cache root: `$OCPLACE_CACHE`, else `~/.cache/ocplace`."""
    root = os.environ.get("OCPLACE_CACHE") or Path.home() / ".cache" / "ocplace"
    return Path(root).expanduser()


@contextlib.contextmanager
def atomic_path(target: str | os.PathLike):
    """Yields a temporary path beside `target`; renames it onto `target` only on success.

    A crash or kill leaves at most a stray `*.tmp*` file, never a half-written `target`.
    """
    target = Path(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        os.replace(tmp, target)
    finally:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)


def write_bytes_atomic(target: str | os.PathLike, data: bytes) -> None:
    with atomic_path(target) as tmp:
        tmp.write_bytes(data)


def write_text_atomic(target: str | os.PathLike, text: str) -> None:
    write_bytes_atomic(target, text.encode("utf-8"))
