"""Local pool workers end with their command (issue 43, defect 10): after SIGTERM or SIGKILL of the process that
started them, none is left 10 s later. A real LocalExecutor in a real child process, killed at a known point."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time

import pytest

from ocplace.paths import pid_alive
from ocplace.runtime.processes import start_time

COMMAND = """
import sys, time
from pathlib import Path
from ocplace.runtime.executor import ExecutorConfig, Task
from ocplace.runtime.opening import open_executor
from worker_tasks import report_and_sleep

folder = Path(sys.argv[1])
with open_executor(ExecutorConfig(workers=2)) as executor:
    handles = [executor.submit(Task(report_and_sleep, (str(folder / f"worker{k}"),))) for k in range(2)]
    executor.wait(handles)
"""


@pytest.mark.parametrize("signal_number", [signal.SIGTERM, signal.SIGKILL])
def test_pool_workers_end_with_their_command(tmp_path, signal_number):
    (tmp_path / "worker_tasks.py").write_text(
        "import os, time\n\n\ndef report_and_sleep(path):\n"
        "    open(path, 'w').write(str(os.getpid()))\n    time.sleep(600)\n"
    )
    command = subprocess.Popen([sys.executable, "-c", COMMAND, str(tmp_path)], cwd=tmp_path, env=_env(tmp_path))
    reports = [tmp_path / "worker0", tmp_path / "worker1"]
    deadline = time.monotonic() + 120
    while not all(r.is_file() and r.read_text() for r in reports):  # both tasks are running: the known point
        assert command.poll() is None and time.monotonic() < deadline
        time.sleep(0.1)
    workers = [int(r.read_text()) for r in reports]
    command.send_signal(signal_number)
    command.wait(30)
    deadline = time.monotonic() + 10
    while any(pid_alive(pid) for pid in workers) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not any(pid_alive(pid) for pid in workers)


def _env(folder) -> dict:
    import os

    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(folder), os.environ.get("PYTHONPATH", "")])}


FAST_POLICY = """
import os, time
from pathlib import Path


def place(observation):
    # Answers only once the slow policy has begun, so that the kill finds the slow one at work.
    while not Path(os.environ["OCPLACE_TEST_PIDS"]).exists():
        time.sleep(0.05)
    return (0.0, 0.0)
"""

SLOW_POLICY = """
import os, time


def place(observation):
    with open(os.environ["OCPLACE_TEST_PIDS"], "a") as pids:  # its own process and the evaluation's worker
        pids.write(f"{os.getpid()} {os.getppid()}\\n")
    time.sleep(1.0)
    return (0.05, 0.0)
"""


def test_a_killed_evaluation_on_two_workers_leaves_no_process_and_resumes_what_it_finished(smoke_dataset, tmp_path):
    """Issue 43's target for `evaluate --workers 2`: SIGKILL once the first evaluation is in (the slow policy
    mid-scene in its own process under the other worker); none of its processes is left 10 s later; the same
    command again reuses the finished evaluation byte for byte and scores the other."""
    from ocplace.experiments.evaluation import DIE_AFTER_EVALUATIONS_ENV

    (tmp_path / "fast_policy_of_the_kill_test.py").write_text(FAST_POLICY)
    (tmp_path / "slow_policy_of_the_kill_test.py").write_text(SLOW_POLICY)
    fast, slow = "fast_policy_of_the_kill_test:place", "slow_policy_of_the_kill_test:place"
    command = [sys.executable, "-m", "ocplace.cli", "evaluate", "--dataset", str(smoke_dataset), "--subsets", "seen"]
    command += ["--limit", "3", "--physical", "0", "--backbone", "none", "--workers", "2", "--out", "results.json"]
    command += ["--policy", fast, "--policy", slow]
    env = _env(tmp_path) | {"OCPLACE_TEST_PIDS": str(tmp_path / "pids")}
    killed = subprocess.run(command, cwd=tmp_path, env=env | {DIE_AFTER_EVALUATIONS_ENV: "1"}, capture_output=True)
    assert killed.returncode == -signal.SIGKILL, killed.stderr.decode()[-2000:]
    assert not (tmp_path / "results.json").exists()
    (stored,) = (tmp_path / "results.evaluations").glob("fast_policy_of_the_kill_test_place-*.json")
    left = {int(pid) for line in (tmp_path / "pids").read_text().splitlines() for pid in line.split()}
    deadline = time.monotonic() + 10
    while any(pid_alive(pid) for pid in left) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not any(pid_alive(pid) for pid in left), "a worker or a policy's process outlived its command"
    stored_text = stored.read_text()

    resumed = subprocess.run(command, cwd=tmp_path, env=env, capture_output=True, text=True)
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    assert f"evaluated {fast} stored by an earlier, interrupted command" in resumed.stdout
    assert not (tmp_path / "results.evaluations").exists()
    from ocplace.eval.results import evaluation_to_json, evaluations, read_results

    results = read_results(tmp_path / "results.json")
    by_method = {e.method: e for e in evaluations(results)}
    assert evaluation_to_json(by_method[fast]) == json.loads(stored_text)["evaluation"]  # reused as stored
    modes = {m: [o.mode for o in e.subsets["seen"]] for m, e in by_method.items()}
    assert modes == {fast: [(0.0, 0.0)] * 3, slow: [(0.05, 0.0)] * 3}


STOPPED_POLICY = """
import os, signal, subprocess


def place(observation):
    child = subprocess.Popen(["sleep", "400"], start_new_session=True)
    with open(os.environ["OCPLACE_TEST_PIDS"], "a") as pids:  # itself, its worker and what it started
        pids.write(f"{os.getpid()} {os.getppid()} {child.pid}\\n")
    os.kill(os.getpid(), signal.SIGSTOP)  # frozen mid-scene: its own watcher cannot run
    return (0.0, 0.0)
"""


@pytest.mark.slow  # the default suite's 15 min budget on 2 cores (docs/performance.md)
def test_a_stopped_policy_and_what_it_started_end_when_the_command_is_killed(smoke_dataset, tmp_path):
    """Issue 60, item 4: `kill -9` of `evaluate` while the policy's process is stopped (SIGSTOP, a debugger, a frozen
    cgroup): its worker, seeing its command gone, kills everything below it; nothing is left 15 s later."""
    (tmp_path / "stopped_policy_of_the_kill_test.py").write_text(STOPPED_POLICY)
    command = [sys.executable, "-m", "ocplace.cli", "evaluate", "--dataset", str(smoke_dataset), "--subsets", "seen"]
    command += ["--limit", "1", "--physical", "0", "--backbone", "none", "--workers", "2", "--out", "results.json"]
    command += ["--policy", "stopped_policy_of_the_kill_test:place", "--scene-timeout", "300", "--no-progress"]
    pids_file = tmp_path / "pids"
    running = subprocess.Popen(command, cwd=tmp_path, env=_env(tmp_path) | {"OCPLACE_TEST_PIDS": str(pids_file)})
    deadline = time.monotonic() + 120
    while not (pids_file.is_file() and pids_file.read_text().endswith("\n")):  # the known point: it has stopped
        assert running.poll() is None and time.monotonic() < deadline
        time.sleep(0.1)
    time.sleep(0.5)
    running.kill()
    running.wait(30)
    left = [int(pid) for pid in pids_file.read_text().split()]
    deadline = time.monotonic() + 15
    while any(pid_alive(pid) for pid in left) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not any(pid_alive(pid) for pid in left), "a stopped policy, its worker or its child outlived the command"


ORPHANING_POLICY = """
import ctypes, os, signal, subprocess


def place(observation):
    # A daemon by double fork (its shell ends at once, in a session of its own), then the policy never returns.
    shell = subprocess.run(["sh", "-c", "setsid sleep 400 >/dev/null 2>&1 & echo $!"], capture_output=True, text=True)
    with open(os.environ["OCPLACE_TEST_PIDS"], "a") as pids:
        pids.write(f"{os.getpid()} {shell.stdout.strip()}\\n")
    if os.environ["OCPLACE_TEST_MODE"] == "stopped":
        os.kill(os.getpid(), signal.SIGSTOP)
    else:  # native code holding the GIL: no thread of the process runs Python, its watcher included
        ctypes.PyDLL(None).sleep(400)
    return (0.0, 0.0)
"""

HOSTING_COMMAND = """
from ocplace.methods.policy_host import PolicyHost

PolicyHost("orphaning_policy_of_the_reap_test:place").request(("place", None), 300)
"""


@pytest.mark.parametrize("mode", ["stopped", "native"])
def test_nothing_a_policy_started_outlives_a_command_killed_with_sigkill(tmp_path, monkeypatch, mode):
    """Issue 60, item 4: a command hosting a policy in its own process is killed with SIGKILL while the policy has a
    double-forked daemon and is stopped (the kernel's SIGHUP to an orphaned group wakes it: it ends its tree) or
    stuck in native code (nothing of it runs: the next policy started ends it and its daemon, from its note)."""
    (tmp_path / "orphaning_policy_of_the_reap_test.py").write_text(ORPHANING_POLICY)
    (tmp_path / "fast_policy_of_the_reap_test.py").write_text("def place(observation):\n    return (0.0, 0.0)\n")
    pids_file, notes = tmp_path / "pids", tmp_path / "cache" / "processes"
    env = _env(tmp_path) | {"OCPLACE_TEST_PIDS": str(pids_file), "OCPLACE_CACHE": str(tmp_path / "cache")}
    running = subprocess.Popen(
        [sys.executable, "-c", HOSTING_COMMAND], cwd=tmp_path, env=env | {"OCPLACE_TEST_MODE": mode}
    )
    deadline = time.monotonic() + 60
    while not (pids_file.is_file() and pids_file.read_text().endswith("\n")):  # the known point: it is stuck
        assert running.poll() is None and time.monotonic() < deadline
        time.sleep(0.1)
    running.kill()
    running.wait(30)
    left = [int(pid) for pid in pids_file.read_text().split()]
    if mode == "native":
        time.sleep(2)  # past the watcher's poll: were it able to run, it would have ended them
        assert all(pid_alive(pid) for pid in left), "the stuck policy ended by itself: this case tests nothing"
        assert [path.name for path in notes.iterdir()] == [f"{left[0]}-{start_time(left[0])}.json"]
        monkeypatch.setenv("OCPLACE_CACHE", str(tmp_path / "cache"))
        monkeypatch.syspath_prepend(str(tmp_path))
        from ocplace.methods.policy_host import PolicyHost

        host = PolicyHost("fast_policy_of_the_reap_test:place")
        assert host.request(("place", None), 30) == {"mode": [0.0, 0.0]}
        host.stop()
        assert list(notes.iterdir()) == [], "a note outlived its process"
    deadline = time.monotonic() + 10
    while any(pid_alive(pid) for pid in left) and time.monotonic() < deadline:  # zombies until init reaps them
        time.sleep(0.1)
    assert not any(pid_alive(pid) for pid in left), "a policy or its daemon outlived the command"
