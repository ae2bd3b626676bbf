"""The flags that choose where a command's tasks run: `--workers`, `--ray`, `--ray-address`."""

from __future__ import annotations

import argparse
from typing import Literal

from ocplace.cli.options import MAX_WORKERS, count
from ocplace.runtime.executor import ExecutorConfig


def add_executor_arguments(parser: argparse.ArgumentParser, tasks: str) -> None:
    """`tasks` says what runs as tasks, e.g. "each scene is a task"."""
    group = parser.add_argument_group("where it runs", f"{tasks}; see docs/distributed.md")
    group.add_argument(
        "--workers", type=count(0, MAX_WORKERS), default=0, help="local processes, or CPUs of --ray (default: all)"
    )
    group.add_argument("--ray", action="store_true", help="run the tasks on a local Ray instance started here")
    group.add_argument(
        "--ray-address",
        metavar="ADDRESS",
        help="join a running Ray cluster instead: auto, HOST:PORT or ray://HOST:PORT (implies --ray)",
    )


def executor_config(args: argparse.Namespace) -> ExecutorConfig:
    kind: Literal["local", "ray"] = "ray" if args.ray or args.ray_address else "local"
    progress = not getattr(args, "no_progress", False)  # a command without --no-progress shows its workers'
    return ExecutorConfig(kind=kind, workers=args.workers, address=args.ray_address, progress=progress)
