"""The Ray executor: starts a local Ray instance, or joins a running cluster, and runs tasks on it.

A Ray instance this executor starts lives in a short temporary folder (Ray's socket paths must stay
under 107 characters), named after the command's pid, and is shut down, with every process it started,
when the executor closes. A command killed with SIGKILL cannot shut it down: Ray's DashboardAgent and
RuntimeEnvAgent outlive it, with the folder. The next start reaps them: it ends the processes holding
files in the folder of an instance whose command is gone, and removes the folder.
Joining a cluster first probes the head's port, so an unreachable head fails within
`connect_timeout_s` instead of hanging (ray.init itself has no timeout).
"""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
from pathlib import Path

from ocplace.errors import ClusterError, ConfigError
from ocplace.paths import cache_dir, pid_alive
from ocplace.runtime.executor import Executor, ExecutorConfig, Task, run_task, run_task_in_fresh_process

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


class RayExecutor(Executor):
    def __init__(self, config: ExecutorConfig):
        import ray

        os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")  # no usage report from an offline machine
        self._ray, self._config, self._tasks = ray, config, {}
        self._temp_dir, self._env = None, worker_env()
        options = dict(
            include_dashboard=False,
            configure_logging=False,
            log_to_driver=False,
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
            self._run = {False: ray.remote(run_task), True: ray.remote(max_calls=1)(run_task_in_fresh_process)}
        except BaseException:
            self.close()
            raise

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
        options = dict(num_cpus=min(task.cpus, self._largest_node), max_retries=self._config.task_retries)
        env = worker_env()
        if env != self._env:  # e.g. a test hook set after Ray started: workers with this environment run it
            options["runtime_env"] = {"env_vars": env}
        handle = self._run[task.pinned].options(**options).remote(task)
        self._tasks[handle] = task
        return handle

    def wait(self, handles):
        done, pending = self._ray.wait(handles, num_returns=1)
        if pending:  # collect whatever else has finished too: one wait per task would be quadratic
            more, pending = self._ray.wait(pending, num_returns=len(pending), timeout=0)
            done += more
        return done, pending

    def result(self, handle):
        exceptions = self._ray.exceptions
        task = self._tasks.pop(handle)
        try:
            return self._ray.get(handle)
        except exceptions.RayTaskError as error:
            if isinstance(error.cause, Exception):
                raise error.cause from None
            raise
        except exceptions.RayError as error:
            raise ClusterError(
                f"Ray lost task {task.fn.__module__}.{task.fn.__qualname__} after "
                f"{self._config.task_retries} retries: {type(error).__name__}: {error}"
            ) from None

    def release_workers(self):
        """Ray ends idle workers itself."""

    def close(self):
        if self._ray.is_initialized():
            self._ray.shutdown()
        if self._temp_dir is not None:
            shutil.rmtree(self._temp_dir, ignore_errors=True)
            self._temp_dir = None
