"""Issue 60, items 3 and 4: a hosted policy (`MODULE:CALLABLE` in a process of its own) can never hang the harness
or outlive it. Each misbehaviour happens once, on the first request; the host stops that process (and all it
started) within the deadline, and the next request is answered by a fresh one. Real processes, real pipes."""

from __future__ import annotations

import os
import time

import numpy as np
import pytest

from ocplace.errors import PolicyProcessEnded, SceneTimeout
from ocplace.paths import pid_alive

POLICIES = """
import gc, os, signal, struct, subprocess, threading, time
from multiprocessing.connection import Connection
from pathlib import Path

FOLDER = Path(os.environ["OCPLACE_TEST_FOLDER"])


def _first():
    mark = FOLDER / "misbehaved"
    if mark.exists():
        return False
    mark.write_text("once")
    return True


def _pipe():
    return next(o for o in gc.get_objects() if isinstance(o, Connection) and not o.closed)


def _frame(data):
    _pipe().send_bytes(data)
    time.sleep(600)


def not_json(observation):
    if _first():
        _frame(b"this is not json")
    return (0.0, 0.0)


def too_deep(observation):
    if _first():
        _frame(b"[" * 200_000 + b"]" * 200_000)
    return (0.0, 0.0)


def no_mode(observation):
    if _first():
        _frame(b'{"surprise": 1}')
    return (0.0, 0.0)


def header_then_sleep(observation):
    if _first():
        os.write(_pipe().fileno(), struct.pack("!i", 1000))
        time.sleep(600)
    return (0.0, 0.0)


def huge_answer(observation):
    if _first():
        os.write(_pipe().fileno(), struct.pack("!i", 2**30))
        time.sleep(600)
    return (0.0, 0.0)


def frozen_after_answering(observation):
    if _first():
        threading.Thread(target=lambda: (time.sleep(0.2), os.kill(os.getpid(), signal.SIGSTOP))).start()
    return (0.0, 0.0)


class ReturnsNone:
    def describe(self):
        return {"name": "returns none"}

    def run(self, scenes, key):
        return [None for _ in scenes]


def starts_processes(observation):
    if _first():
        kept = [subprocess.Popen(["sleep", "400"]), subprocess.Popen(["sleep", "400"], start_new_session=True)]
        pid = os.fork()
        if pid == 0:
            time.sleep(400)
            os._exit(0)
        (FOLDER / "started").write_text(" ".join(str(p) for p in [*(k.pid for k in kept), pid]))
        time.sleep(600)
    return (0.0, 0.0)
"""

OBSERVATION = {"rgb": np.zeros((480, 640, 3), np.uint8), "depth": np.zeros((480, 640), np.float32)}  # 2 MB


@pytest.fixture
def policies(tmp_path, monkeypatch):
    (tmp_path / "misbehaving_policies_of_the_host_test.py").write_text(POLICIES)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("OCPLACE_TEST_FOLDER", str(tmp_path))
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(tmp_path), os.environ.get("PYTHONPATH", "")]))
    return tmp_path


@pytest.mark.parametrize(
    "name, error, message",
    [
        ("not_json", PolicyProcessEnded, "sent 'this is not json', which is no answer (it is not JSON)"),
        ("too_deep", PolicyProcessEnded, "which is no answer (it is not JSON)"),
        ("no_mode", PolicyProcessEnded, "which is no answer (an object with mode or error is needed)"),
        ("header_then_sleep", SceneTimeout, "timeout: the policy took more than 3 s (--scene-timeout)"),
        ("huge_answer", PolicyProcessEnded, "announced an answer past 4,194,304 bytes"),
        ("starts_processes", SceneTimeout, "timeout: the policy took more than 3 s"),
    ],
)
def test_a_misbehaving_answer_fails_its_scene_within_the_deadline_and_the_next_is_answered(
    policies, name, error, message
):
    from ocplace.methods.policy_host import PolicyHost

    host = PolicyHost(f"misbehaving_policies_of_the_host_test:{name}")
    try:
        began = time.monotonic()
        with pytest.raises(error, match=message.replace("(", r"\(").replace(")", r"\)")):
            host.request(("place", OBSERVATION), 3.0)
        assert time.monotonic() - began < 30
        assert host.request(("place", OBSERVATION), 3.0) == {"mode": [0.0, 0.0]}  # a fresh process
    finally:
        host.stop()
    if name == "starts_processes":  # what it started ended with it, `start_new_session` and a fork too
        started = [int(pid) for pid in (policies / "started").read_text().split()]
        deadline = time.monotonic() + 10
        while any(pid_alive(pid) for pid in started) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not any(pid_alive(pid) for pid in started)


def test_a_process_frozen_between_scenes_costs_the_deadline_not_the_evaluation(policies):
    """SIGSTOP after its first answer: the next 2 MB observation cannot be handed over; the send is bounded too."""
    from ocplace.methods.policy_host import PolicyHost

    host = PolicyHost("misbehaving_policies_of_the_host_test:frozen_after_answering")
    try:
        assert host.request(("place", OBSERVATION), 3.0) == {"mode": [0.0, 0.0]}
        time.sleep(0.5)  # it stops itself 0.2 s after answering
        began = time.monotonic()
        with pytest.raises(SceneTimeout):
            host.request(("place", OBSERVATION), 3.0)
        assert time.monotonic() - began < 30
        assert host.request(("place", OBSERVATION), 3.0) == {"mode": [0.0, 0.0]}
    finally:
        host.stop()


def test_the_harness_goes_on_after_a_policy_that_answered_garbage(policies, smoke_dataset):
    """Through `evaluate_policy`: the scene of the bad answer fails with its reason, the next scenes are placed."""
    from ocplace.eval.harness import EvalSettings
    from ocplace.methods.external_policy import evaluate_policy

    settings = EvalSettings(backbone="none", subsets=("seen",), physical_scenes=0, limit=3)
    began = time.monotonic()
    results = evaluate_policy(
        "misbehaving_policies_of_the_host_test:no_mode", smoke_dataset, settings, scene_timeout_s=5
    )
    assert time.monotonic() - began < 60
    scenes = results["evaluations"][0]["subsets"]["seen"]["scenes"]
    assert "which is no answer" in scenes[0]["failure"]
    assert [scene["mode"] for scene in scenes[1:]] == [[0.0, 0.0], [0.0, 0.0]]


def test_a_hosted_method_returning_no_method_output_is_scored_as_in_process(policies, smoke_dataset):
    """Item 10: "malformed output: NoneType, not a MethodOutput", as the same Method gets in the evaluation's
    process, not a TypeError of the host's."""
    from ocplace.eval.harness import EvalSettings
    from ocplace.methods.external_policy import evaluate_policy

    settings = EvalSettings(backbone="none", subsets=("seen",), physical_scenes=0, limit=2)
    hosted = evaluate_policy("misbehaving_policies_of_the_host_test:ReturnsNone", smoke_dataset, settings)
    failures = [scene["failure"] for scene in hosted["evaluations"][0]["subsets"]["seen"]["scenes"]]
    assert failures == ["malformed output: NoneType, not a MethodOutput"] * 2
