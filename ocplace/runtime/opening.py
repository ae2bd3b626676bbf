"""Opening the executor a configuration describes: this machine's processes, or a Ray cluster.

Apart from `executor.py`, which `ray_executor.py` builds on, so that neither imports the other back.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Iterator

from ocplace.runtime.executor import Executor, ExecutorConfig, LocalExecutor, usable_workers

log = logging.getLogger(__name__)


@contextlib.contextmanager
def open_executor(config: ExecutorConfig | None = None) -> Iterator[Executor]:
    """The executor `config` describes, closed (and a Ray instance it started shut down) on exit."""
    config = config or ExecutorConfig()
    clamped = usable_workers(config.workers)[1]
    if clamped is not None and config.address is None:  # a cluster joined sizes itself
        log.warning(clamped)
    executor: Executor
    if config.kind == "ray":
        from ocplace.runtime.ray_executor import RayExecutor

        executor = RayExecutor(config)  # shuts down what it started if it fails half-way
    else:
        executor = LocalExecutor(config.cpus(), config.progress)
    try:
        yield executor
    finally:
        executor.close()
