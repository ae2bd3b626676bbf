"""Finding and ending the processes below a process: what a hosted policy started, what a worker leaves, and what
a command killed with SIGKILL left behind (reaped by the next command, as `ray start` reaps a dead session).

Read from `/proc` (Linux, where ocplace runs its workers): a process's parent link, not its group or session, so
a child that left its parent's group with `setsid` is found while its parent lives; a process that made itself a
subreaper (`become_subreaper`) keeps the orphans of its children below it, so a double fork is found too.
"""

from __future__ import annotations

import contextlib
import ctypes
import json
import logging
import os
import signal
from pathlib import Path

log = logging.getLogger(__name__)

PR_SET_CHILD_SUBREAPER = 36  # linux/prctl.h


def descendants(pid: int) -> list[int]:
    """Every live process below `pid` by parent links, nearest first."""
    children: dict[int, list[int]] = {}
    for entry in os.scandir("/proc"):
        if entry.name.isdigit():
            fields = _stat_fields(int(entry.name))
            if fields:
                children.setdefault(int(fields[1]), []).append(int(entry.name))
    found, stack = [], [pid]
    while stack:
        below = children.get(stack.pop(), [])
        found += below
        stack += below
    return found


def kill_tree(pid: int, group: bool = True) -> None:
    """SIGKILL to every process below `pid` (a stopped one too), and with `group` to `pid`'s process group (which
    `pid` leads) as well; `pid` itself only through its group."""
    for target in descendants(pid):
        with contextlib.suppress(OSError):
            os.kill(target, signal.SIGKILL)
    if group:
        with contextlib.suppress(OSError):
            os.killpg(pid, signal.SIGKILL)


def become_subreaper() -> None:
    """Makes this process the parent of its descendants' orphans (Linux 3.4+), so `descendants` finds a process a
    policy started through a child that has since ended; where the call is missing, nothing changes."""
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0)


def start_time(pid: int) -> int | None:
    """When `pid` started, in clock ticks since boot (tells a process from a later one given its pid); None when
    no such process runs (a zombie included)."""
    fields = _stat_fields(pid)
    return int(fields[19]) if fields and fields[0] != "Z" else None


def _stat_fields(pid: int) -> list[str] | None:
    """`/proc/<pid>/stat` from its third field (state, parent, ...); None when it ended while we looked."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as handle:
            return handle.read().rsplit(b")", 1)[1].decode().split()
    except (OSError, IndexError, UnicodeDecodeError):
        return None


def record_process(folder: Path, pid: int) -> Path | None:
    """Notes in `folder` that this process (the owner) started `pid`, so that if the owner dies by SIGKILL the next
    command ends `pid` and all below it (`reap_leftovers`); the note's path (None when it could not be written:
    the process still ends with its owner in every other way)."""
    started, owner_started = start_time(pid), start_time(os.getpid())
    note = {"pid": pid, "start": started, "owner": os.getpid(), "owner_start": owner_started}
    path = folder / f"{pid}-{started}.json"
    try:
        folder.mkdir(parents=True, exist_ok=True)
        temporary = path.with_suffix(f".{os.getpid()}.tmp")
        temporary.write_text(json.dumps(note))
        temporary.replace(path)
    except OSError as error:
        log.warning("could not note the policy process %d in %s (%s)", pid, folder, error)
        return None
    return path


def forget_process(path: Path | None) -> None:
    """Removes a note of `record_process` once its process was ended by its owner."""
    if path is not None:
        with contextlib.suppress(OSError):
            path.unlink()


def reap_leftovers(folder: Path) -> list[int]:
    """Ends every process noted in `folder` whose owner is gone (killed with SIGKILL, so nothing of it could end
    them), with all below it and its group, and removes those notes; the pids ended."""
    reaped: list[int] = []
    if not folder.is_dir():
        return reaped
    for path in folder.glob("*.json"):
        note = _read_note(path)
        if note is None or start_time(note["owner"]) == note["owner_start"]:
            continue  # damaged (removed below), or its owner still runs and will end it
        if start_time(note["pid"]) == note["start"]:
            reaped += [note["pid"], *descendants(note["pid"])]
            kill_tree(note["pid"])
        forget_process(path)
    if reaped:
        log.warning("ended %d processes a killed ocplace command had left: %s", len(reaped), reaped)
    return reaped


def _read_note(path: Path) -> dict[str, int] | None:
    """A note of `record_process`; None (and the note removed) when it is not one."""
    try:
        with open(path, "rb") as handle:
            note = json.loads(handle.read(1024))
        if isinstance(note, dict) and all(isinstance(note.get(k), int) for k in ("pid", "start", "owner")):
            return note
    except (OSError, ValueError):
        pass
    forget_process(path)
    return None
