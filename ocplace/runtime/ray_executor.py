"""The Ray executor: starts a local Ray instance, or joins a running cluster, and runs tasks on it.

A Ray instance this executor starts lives in a short temporary folder (Ray's socket paths must stay
under 107 characters), named after the command's pid, and is shut down, with every process it started,
when the executor closes. A command killed with SIGKILL cannot shut it down: Ray's DashboardAgent and
RuntimeEnvAgent outlive it, with the folder. The next start reaps them: it ends the processes holding
files in the folder of an instance whose command is gone, and removes the folder.
Joining a cluster first probes the head's port, so an unreachable head fails within
`connect_timeout_s` instead of hanging (ray.init itself has no timeout).

A pinned task runs on a long-lived worker of its JAX width, as on the local pool: a Ray actor that pinned
its width when it started and keeps its imports, loaded backbones and compiled functions from task to
task. An actor holds its CPUs while it lives, idle or not (Ray's resources are per actor, not per call),
so the executor queues calls itself: a call waits for an idle actor of its width, or for room to start
one, and idle actors of another width are ended to make that room. A killed actor is restarted, and
the call it was running retried, up to `task_retries` times.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

from ocplace.errors import ClusterError, ConfigError
from ocplace.paths import cache_dir, pid_alive
from ocplace.runtime.executor import Executor, ExecutorConfig, Task, run_task

TEMP_ROOT = "/tmp"
TEMP_PREFIX = "ocray-"  # then the pid of the command that started the instance, "-", random characters

# Forwarded to every worker, so the tasks of a cluster read and write what the driver means.
FORWARDED_ENV = ("OCPLACE_CACHE", "MUJOCO_GL", "PYOPENGL_PLATFORM")
TEST_HOOK_PREFIX = "OCPLACE_TEST_"  # test hooks (e.g. a worker that kills itself) reach the workers too

log = logging.getLogger(__name__)


def worker_env() -> dict[str, str]:
    env = {name: os.environ[name] for name in FORWARDED_ENV if name in os.environ}
    env |= {name: value for name, value in os.environ.items() if name.startswith(TEST_HOOK_PREFIX)}
    return env | {"OCPLACE_CACHE": str(cache_dir())}


def head_endpoint(address: str) -> tuple[str, int] | None:
    """(host, port) to probe for `address`; None for "auto" (Ray finds the cluster on this machine)."""
    if address == "auto":
        return None
    hostport = address.removeprefix("ray://")
    host, sep, port = hostport.rpartition(":")
    if not sep or not host or not port.isdigit():
        raise ConfigError(f"--ray-address {address!r} is not auto, HOST:PORT or ray://HOST:PORT")
    return host, int(port)


def probe_head(address: str, timeout_s: float) -> None:
    """ClusterError unless something listens at the head's address (or, for auto, a cluster runs here)."""
    endpoint = head_endpoint(address)
    if endpoint is None:  # auto: Ray looks in its own places; the preflight join tells
        return
    try:
        socket.create_connection(endpoint, timeout=timeout_s).close()
    except OSError as error:
        raise ClusterError(
            f"cannot reach the Ray head at {address} ({error}); check the address and that `ray start --head` "
            "runs there and its port is open to this machine"
        ) from None


def preflight(address: str, timeout_s: float) -> None:
    """Joins the cluster once in a child process, so a head that accepts connections but never answers
    as Ray (ray.init has no timeout, and Ray ends a process that waits too long) fails in bounded time."""
    code = f"import ray; ray.init(address={address!r}, include_dashboard=False); ray.shutdown()"
    env = os.environ | {"RAY_USAGE_STATS_ENABLED": "0"}
    try:
        joined = subprocess.run(
            [sys.executable, "-c", code], capture_output=True, text=True, timeout=timeout_s, env=env
        )
    except subprocess.TimeoutExpired:
        raise ClusterError(
            f"the Ray head at {address} did not answer within {timeout_s:.0f} s; check that it is a Ray head "
            "of the same Ray version (ray==2.60.0) and that its node ports are open to this machine"
        ) from None
    if joined.returncode != 0:
        last = (joined.stderr.strip().splitlines() or ["(no output)"])[-1]
        hint = "; start one with `ray start --head` or use --ray for a local instance" if address == "auto" else ""
        raise ClusterError(f"could not join the Ray cluster at {address}: {last}{hint}")


def reap_abandoned_instances(root: str = TEMP_ROOT) -> list[int]:
    """Ends the processes left by local Ray instances whose command is gone, and removes their folders;
    returns the pids ended. An instance whose command still runs is left alone."""
    ended = []
    for folder in Path(root).glob(f"{TEMP_PREFIX}*-*"):
        owner = folder.name.removeprefix(TEMP_PREFIX).split("-")[0]
        if not owner.isdigit() or pid_alive(int(owner)):
            continue
        left = _processes_using(folder)
        for pid in left:
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.kill(pid, signal.SIGKILL)
        shutil.rmtree(folder, ignore_errors=True)
        log.info("removed %s, left by a Ray instance whose command was killed; ended processes %s", folder, left)
        ended += left
    return ended


def _processes_using(folder: Path) -> list[int]:
    """The pids of the processes that hold a file under `folder` open (a Ray process keeps its logs open)."""
    inside_folder = f"{folder}/"
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        with contextlib.suppress(OSError):  # the process ended, or is not ours to read
            if any(os.readlink(fd).startswith(inside_folder) for fd in (entry / "fd").iterdir()):
                found.append(int(entry.name))
    return found


class PinnedWorker:
    """A Ray actor that starts JAX `width` CPUs wide and then runs pinned task after task."""

    def __init__(self, width: int, progress: bool = True):
        from ocplace.runtime.executor import init_worker

        init_worker(width, progress)

    def run(self, task: Task):
        return task.fn(*task.args)


@dataclasses.dataclass(eq=False)
class _Call:
    """A submitted task: queued here until it has CPUs (and, when pinned, an actor), then running on Ray."""

    task: Task
    cpus: int  # what it holds on the cluster: its width, at most the largest node's CPUs
    ref: Any = None  # Ray's object ref, once started (Ray ships no types for it)
    actor: Any = None  # the actor it runs on (pinned tasks)
    key: tuple = ()  # an actor's kind: (JAX width, worker environment)
    done: bool = False
    value: object = None
    error: BaseException | None = None


class RayExecutor(Executor):
    def __init__(self, config: ExecutorConfig):
        import ray

        os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")  # no usage report from an offline machine
        self._ray, self._config = ray, config
        self._queued: list[_Call] = []
        self._running: dict[object, _Call] = {}  # by object ref
        self._idle: dict[tuple, list] = {}  # (width, worker environment) -> idle actors, oldest first
        self._actor_cpus: dict[object, int] = {}  # every live actor -> the CPUs it holds
        self._held = 0  # CPUs held by live actors and running unpinned tasks
        self._temp_dir, self._env = None, self._worker_env()
        options = dict(
            include_dashboard=False,
            configure_logging=False,
            log_to_driver=config.progress,  # the workers' progress lines, printed here
            runtime_env={"env_vars": self._env},
        )
        if config.address is None:
            reap_abandoned_instances()
            self._temp_dir = tempfile.mkdtemp(prefix=f"{TEMP_PREFIX}{os.getpid()}-", dir=TEMP_ROOT)
            # "local": a new instance even where RAY_ADDRESS names a cluster (--ray-address joins one).
            options |= dict(address="local", num_cpus=config.cpus(), _temp_dir=self._temp_dir)
        else:
            probe_head(config.address, min(5.0, config.connect_timeout_s))
            options |= dict(address=config.address)
        self._init(options)
        try:
            self.capacity = max(1, int(ray.cluster_resources().get("CPU", 1)))
            # A task asking for more CPUs than any node has would wait forever: it gets the largest node.
            self._largest_node = max(
                (node["Resources"].get("CPU", 0) for node in ray.nodes() if node["Alive"]), default=1
            )
            self._remote_task = ray.remote(run_task)
            self._actor_class = ray.remote(PinnedWorker)
        except BaseException:
            self.close()
            raise

    def _worker_env(self) -> dict[str, str]:
        """`worker_env()` and the progress mode of this command's workers (an unpinned task's too)."""
        from ocplace.runtime.progress import WORKER_PROGRESS_ENV, worker_progress_mode

        return worker_env() | {WORKER_PROGRESS_ENV: worker_progress_mode(self._config.progress)}

    def _init(self, options: dict) -> None:
        where = self._config.address or "this machine"
        if self._config.address is not None:
            preflight(self._config.address, self._config.connect_timeout_s)
        try:
            self._ray.init(**options)
        except Exception as error:
            self.close()
            raise ClusterError(f"could not start or join Ray at {where}: {error}") from error

    def submit(self, task: Task):
        call = _Call(task, max(1, min(task.cpus, self._largest_node)))
        self._queued.append(call)
        self._start_queued()
        return call

    def _start_queued(self) -> None:
        """Starts every queued call that has CPUs now, in the order they were submitted."""
        env = self._worker_env()
        runtime = {} if env == self._env else {"runtime_env": {"env_vars": env}}  # e.g. a test hook set late
        for call in list(self._queued):
            call.key = (call.task.cpus, tuple(sorted(env.items())))
            if call.task.pinned and self._idle.get(call.key):
                call.actor = self._idle[call.key].pop(0)
            elif self._make_room(call.cpus):
                self._held += call.cpus
                if call.task.pinned:
                    call.actor = self._actor_class.options(
                        num_cpus=call.cpus,
                        max_restarts=self._config.task_retries,
                        max_task_retries=self._config.task_retries,
                        **runtime,
                    ).remote(call.task.cpus, self._config.progress)
                    self._actor_cpus[call.actor] = call.cpus
            else:
                continue
            if call.task.pinned:
                call.ref = call.actor.run.remote(call.task)
            else:
                options = dict(num_cpus=call.cpus, max_retries=self._config.task_retries, **runtime)
                call.ref = self._remote_task.options(**options).remote(call.task)
            self._queued.remove(call)
            self._running[call.ref] = call

    def _make_room(self, cpus: int) -> bool:
        """Whether `cpus` more CPUs can be held, after ending idle actors (oldest first) as needed."""
        idle = [(key, actor) for key, actors in self._idle.items() for actor in actors]
        if self._held + cpus - sum(self._actor_cpus[actor] for _, actor in idle) > self.capacity:
            return False  # not even with every idle actor ended: wait for a running call
        for key, actor in idle:
            if self._held + cpus <= self.capacity:
                break
            self._idle[key].remove(actor)
            self._end_actor(actor)
        return True

    def _end_actor(self, actor) -> None:
        self._held -= self._actor_cpus.pop(actor)
        with contextlib.suppress(Exception):  # already dead: nothing to end
            self._ray.kill(actor)

    def wait(self, handles):
        while not any(call.done for call in handles):
            refs = list(self._running)
            if not refs:
                raise ClusterError("no task is running or can start on the Ray cluster: its CPUs are held elsewhere")
            ready, _ = self._ray.wait(refs, num_returns=1)
            more, _ = self._ray.wait(refs, num_returns=len(refs), timeout=0)  # one wait per task would be quadratic
            for ref in dict.fromkeys(ready + more):
                self._finish(self._running.pop(ref))
            self._start_queued()
        return [call for call in handles if call.done], [call for call in handles if not call.done]

    def _finish(self, call: _Call) -> None:
        """Collects a finished call's value or error and frees what it held."""
        exceptions = self._ray.exceptions
        call.done = True
        try:
            call.value = self._ray.get(call.ref)
        except exceptions.RayTaskError as error:
            call.error = error.cause if isinstance(error.cause, Exception) else error
        except exceptions.RayError as error:
            task = call.task
            call.error = ClusterError(
                f"Ray lost task {task.fn.__module__}.{task.fn.__qualname__} after "
                f"{self._config.task_retries} retries: {type(error).__name__}: {error}"
            )
            if call.actor is not None:  # its actor is gone for good
                self._end_actor(call.actor)
                return
        if call.actor is None:
            self._held -= call.cpus
        else:
            self._idle.setdefault(call.key, []).append(call.actor)

    def result(self, handle):
        if handle.error is not None:
            raise handle.error
        return handle.value

    def release_workers(self):
        """Ray ends idle unpinned workers itself; idle actors stay for the pinned tasks to come."""

    def close(self):
        if self._ray.is_initialized():
            self._ray.shutdown()
        if self._temp_dir is not None:
            shutil.rmtree(self._temp_dir, ignore_errors=True)
            self._temp_dir = None
