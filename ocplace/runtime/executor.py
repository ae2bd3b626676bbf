"""One interface for running independent tasks: a local process pool or a Ray cluster.

    with open_executor(ExecutorConfig(kind="ray")) as executor:
        for index, result in map_tasks(executor, [Task(fn, (arg,)) for arg in args]):
            ...

A `Task` is a module-level function and its arguments (both picklable) plus the CPUs it needs.
`local` runs tasks on this machine: in a spawn process pool, or, with one worker, in the calling
process; a task whose JAX width is pinned (`Task.pinned`) runs on a long-lived worker of a pool for
its width, which pinned that width when it started and keeps its imports, loaded backbones and
compiled functions from task to task. A worker that dies fails the tasks its pool had with
ClusterError, the pool is replaced for later tasks, and rerunning the command resumes. `ray` runs
them as Ray tasks, each declaring its CPUs as a Ray resource, and a pinned task on a long-lived Ray
actor of its width (ocplace/runtime/ray_executor.py); a worker that dies has its task retried
(`task_retries`). Tasks write their files themselves, so every worker must see the same paths
(docs/distributed.md).
"""

from __future__ import annotations

import abc
import concurrent.futures
import contextlib
import dataclasses
import logging
import multiprocessing
import os
import threading
import time
import weakref
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures.process import BrokenProcessPool
from typing import Any, Literal

from ocplace.errors import ClusterError, ConfigError

log = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True)
class ExecutorConfig:
    """How a command runs its tasks. None of it changes what the tasks compute."""

    kind: Literal["local", "ray"] = "local"
    workers: int = 0  # local processes, or the CPUs of a Ray instance started here; 0: every CPU
    address: str | None = None  # join this Ray cluster ("auto", "HOST:PORT", "ray://HOST:PORT") instead
    connect_timeout_s: float = 30.0  # an unreachable cluster fails with ClusterError after this long
    task_retries: int = 3  # Ray: times a task whose worker died is run again
    progress: bool = True  # workers print their long steps' progress as lines (`runtime/progress.py`)

    def __post_init__(self):
        if self.kind not in ("local", "ray"):
            raise ConfigError(f"unknown executor {self.kind!r}; use 'local' or 'ray'")
        if self.workers < 0:
            raise ConfigError(f"--workers must be at least 1 (or 0 for every CPU), got {self.workers}")
        if self.address is not None and self.kind != "ray":
            raise ConfigError("a cluster address needs the ray executor (--ray-address implies --ray)")

    def cpus(self) -> int:
        """The CPUs tasks run on here: `workers` (0: every CPU), at most what this machine runs side by side."""
        return usable_workers(self.workers)[0]

    def describe(self) -> str:
        if self.kind == "local":
            return f"local pool of {self.cpus()} process(es)"
        return f"Ray cluster at {self.address}" if self.address else f"local Ray instance with {self.cpus()} CPUs"


# Memory a worker process may need: one making scenes holds the object library, a MuJoCo arena and a renderer
# (about 0.4 GB), a training or an evaluation JAX and its buffers (1 to 2 GB, but those declare two CPUs).
WORKER_MEMORY_GB = 1.0


def usable_workers(requested: int) -> tuple[int, str | None]:
    """(workers to start, why fewer than `requested`): no more than this process's CPUs, nor than the
    memory available holds at WORKER_MEMORY_GB each. More would only share the CPUs (the tasks compute the
    same either way) and can exhaust memory before any task finishes."""
    cpus = len(os.sched_getaffinity(0))
    available_gb = _available_memory_bytes() / 1e9
    allowed = max(1, min(cpus, int(available_gb / WORKER_MEMORY_GB)))
    wanted = requested or cpus
    if wanted <= allowed:
        return wanted, None
    return allowed, (
        f"{'--workers ' + str(requested) if requested else 'one worker per CPU'} is more than this machine runs "
        f"side by side ({cpus} CPUs; {available_gb:.1f} GB of memory available, {WORKER_MEMORY_GB:g} GB per "
        f"worker): using {allowed} workers"
    )


def _available_memory_bytes() -> int:
    """MemAvailable (free memory plus what the page cache would give back)."""
    with contextlib.suppress(OSError, ValueError, StopIteration):
        with open("/proc/meminfo") as meminfo:
            line = next(line for line in meminfo if line.startswith("MemAvailable:"))
        return int(line.split()[1]) * 1024
    return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")


@dataclasses.dataclass(frozen=True)
class Task:
    """`fn(*args)` on a worker. `pinned`: run where JAX was started exactly `cpus` CPUs wide, so jitted
    results are the same bits on any executor (ocplace/runtime/width.py)."""

    fn: Callable[..., Any]
    args: tuple = ()
    cpus: int = 1
    pinned: bool = False


def run_task(task: Task) -> Any:
    """What a new process runs: the task, with JAX pinned to its CPUs first when it asks for that."""
    if task.pinned:
        from ocplace.runtime.width import pin_jax_width

        pin_jax_width(task.cpus)
    return task.fn(*task.args)


class Executor(abc.ABC):
    """Runs tasks concurrently on up to `capacity` CPUs; handles are opaque."""

    capacity: int

    @abc.abstractmethod
    def submit(self, task: Task) -> Any:
        """Starts the task; returns its handle."""

    @abc.abstractmethod
    def wait(self, handles: list) -> tuple[list, list]:
        """Blocks until at least one of `handles` has finished; returns (finished, still running)."""

    @abc.abstractmethod
    def result(self, handle) -> Any:
        """The finished task's return value; re-raises the task's exception."""

    @abc.abstractmethod
    def release_workers(self) -> None:
        """Ends idle workers kept for reuse (and the caches they hold); later tasks start new ones."""

    @abc.abstractmethod
    def close(self) -> None:
        """Releases workers; a Ray instance this executor started is shut down."""


class _Inline:
    """A task the calling process runs when it is waited for, so progress shows task by task."""

    def __init__(self, task: Task):
        self.task = task
        self.value: Any = None
        self.error: Exception | None = None

    def run(self) -> _Inline:
        try:
            self.value = run_task(self.task)
        except Exception as error:
            self.error = error
        return self


class LocalExecutor(Executor):
    """This machine. Unpinned tasks run in one pool (with one worker: in the calling process); pinned
    tasks in one pool per width, whose workers pin JAX to that width as they start and then run task
    after task, so a task finds the imports, backbones and compiled functions of the ones before it."""

    def __init__(self, workers: int, progress: bool = True):
        self.capacity, self._progress = workers, progress
        self._pools: dict[int | None, concurrent.futures.ProcessPoolExecutor] = {}  # JAX width (None: unpinned)
        # The pool each running task's future came from: a pool whose worker died is dropped by the futures it
        # breaks (BrokenProcessPool), the public signal, not its private flag.
        self._origins: weakref.WeakKeyDictionary[concurrent.futures.Future, concurrent.futures.ProcessPoolExecutor]
        self._origins = weakref.WeakKeyDictionary()

    def _pool(self, width: int | None) -> concurrent.futures.ProcessPoolExecutor:
        if width not in self._pools:
            self._pools[width] = concurrent.futures.ProcessPoolExecutor(
                # the graph never runs more than capacity // width tasks of one width at once
                self.capacity if width is None else max(1, self.capacity // width),
                mp_context=multiprocessing.get_context("spawn"),  # forking after JAX or EGL start-up is unsafe
                initializer=init_worker,
                initargs=(width, self._progress),
            )
        return self._pools[width]

    def submit(self, task: Task):
        if not task.pinned and self.capacity == 1:
            return _Inline(task)
        pool = self._pool(task.cpus if task.pinned else None)
        # A pinned task's worker pinned its width when it started.
        future = pool.submit(task.fn, *task.args) if task.pinned else pool.submit(run_task, task)
        self._origins[future] = pool
        return future

    def wait(self, handles):
        inline = next((h for h in handles if isinstance(h, _Inline)), None)
        if inline is not None:
            return [inline.run()], [h for h in handles if h is not inline]
        done, pending = concurrent.futures.wait(handles, return_when=concurrent.futures.FIRST_COMPLETED)
        return [h for h in handles if h in done], [h for h in handles if h in pending]

    def result(self, handle):
        if isinstance(handle, _Inline):
            if handle.error is not None:
                raise handle.error
            return handle.value
        try:
            return handle.result()
        except BrokenProcessPool:
            self._drop_pool(self._origins.get(handle))
            raise ClusterError(
                "a worker process died (killed, out of memory or a crash in native code); what it was doing "
                "is lost, finished work is kept: rerun the command to resume"
            ) from None

    def _drop_pool(self, broken: concurrent.futures.ProcessPoolExecutor | None) -> None:
        """A pool whose worker died refuses every later task: later tasks get a new one."""
        for width, pool in list(self._pools.items()):
            if pool is broken:
                pool.shutdown(wait=False, cancel_futures=True)
                del self._pools[width]

    def release_workers(self):
        if None in self._pools:
            self._pools.pop(None).shutdown()

    def close(self):
        for pool in self._pools.values():
            pool.shutdown(cancel_futures=True)
        self._pools.clear()


def init_worker(width: int | None, progress: bool = True) -> None:
    """Starts a worker (a local pool's process, a Ray actor); one for pinned tasks starts JAX `width` CPUs
    wide before any task can import it. Its long steps print progress lines unless `progress` is off. The worker
    ends itself when the process that started it is gone."""
    from ocplace.runtime.processes import kill_tree
    from ocplace.runtime.progress import WORKER_PROGRESS_ENV, worker_progress_mode

    os.environ["OMP_NUM_THREADS"] = "1"  # one task per CPU; OpenMP (coacd) would oversubscribe
    os.environ[WORKER_PROGRESS_ENV] = worker_progress_mode(progress)
    # What the worker started (a hosted policy's process and its children, a stopped one too) ends with it.
    exit_with_parent(lambda: kill_tree(os.getpid(), group=False))
    if width is not None:
        from ocplace.runtime.width import pin_jax_width

        pin_jax_width(width)


PARENT_CHECK_S = 1.0


def exit_with_parent(before_exit: Callable[[], None] | None = None) -> None:
    """A daemon thread that ends this process within `PARENT_CHECK_S` of its parent's end (SIGTERM or SIGKILL of
    the command: nothing else would, as a pool's idle worker waits on its queue for good), after `before_exit` (a
    policy's process kills its group). Polling, not Linux's parent-death signal, which fires when the *thread* that
    started the process ends."""
    parent = os.getppid()

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(PARENT_CHECK_S)
        if before_exit is not None:
            before_exit()
        os._exit(1)

    threading.Thread(target=watch, name="ocplace-exit-with-parent", daemon=True).start()


def map_tasks(executor: Executor, tasks: Iterable[Task]) -> Iterator[tuple[int, Any]]:
    """(index, result) of every task, in the order they finish; the first task error is raised."""
    indices = {executor.submit(task): index for index, task in enumerate(tasks)}
    pending = list(indices)
    while pending:
        done, pending = executor.wait(pending)
        for handle in done:
            yield indices[handle], executor.result(handle)
