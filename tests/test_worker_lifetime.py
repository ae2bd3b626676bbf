"""Local pool workers end with their command (issue 43, defect 10): after SIGTERM or SIGKILL of the process that
started them, none is left 10 s later. A real LocalExecutor in a real child process, killed at a known point."""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import pytest

from ocplace.paths import pid_alive

COMMAND = """
import sys, time
from pathlib import Path
from ocplace.runtime.executor import ExecutorConfig, Task, open_executor
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
