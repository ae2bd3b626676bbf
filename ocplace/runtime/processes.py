"""Finding and ending the processes below a process: what a hosted policy started, what a worker leaves.

Read from `/proc` (Linux, where ocplace runs its workers): a process's parent link, not its group or session, so
a child that left its parent's group with `setsid` is found while its parent lives.
"""

from __future__ import annotations

import contextlib
import os
import signal


def descendants(pid: int) -> list[int]:
    """Every live process below `pid` by parent links, nearest first."""
    children: dict[int, list[int]] = {}
    for entry in os.scandir("/proc"):
        if entry.name.isdigit():
            try:
                with open(f"/proc/{entry.name}/stat", "rb") as handle:
                    parent = int(handle.read().rsplit(b")", 1)[1].split()[1])
            except (OSError, ValueError, IndexError):
                continue  # it ended while we looked
            children.setdefault(parent, []).append(int(entry.name))
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
