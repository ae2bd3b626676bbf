"""Any policy on the benchmark: `evaluate_policy`, `ocplace evaluate --policy`, and the environment agreeing."""

import dataclasses
import hashlib
import json
import re
import shlex
import sys
import time
from pathlib import Path

import eval_methods
import gymnasium
import numpy as np
import pytest

from ocplace.cli import main
from ocplace.eval.harness import EvalSettings
from ocplace.eval.results import read_results
from ocplace.eval.table import table_one
from ocplace.methods.external_policy import evaluate_policy
from ocplace.sim.dataset.job import listed_scenes
from ocplace.sim.env import ENV_ID
from ocplace.sim.workspace import DEFAULT_TABLE

SUBSETS = ("seen", "unseen_inst")
SETTINGS = EvalSettings(backbone="none", subsets=SUBSETS, physical_scenes=0)


def image_key(rgb: np.ndarray) -> str:
    return hashlib.sha256(rgb.tobytes()).hexdigest()


class MixedPolicy:
    """Seeded, one draw per call: the oracle, a jittered oracle, a random point on the table, or NaN.

    It cheats through a table of oracles keyed by image, so that its outcomes mix successes and failures.
    """

    def __init__(self, oracles: dict[str, np.ndarray]):
        self.oracles = oracles
        self.rng = np.random.default_rng(7)

    def place(self, observation):
        oracle = self.oracles[image_key(observation["rgb"])]
        choice = self.rng.integers(4)
        jitter = self.rng.normal(0.0, 0.03, 2)
        anywhere = self.rng.uniform(DEFAULT_TABLE.bounds[0], DEFAULT_TABLE.bounds[1])
        return (oracle, oracle + jitter, anywhere, np.array([np.nan, 0.0]))[choice]


def oracles_by_image(dataset) -> dict[str, np.ndarray]:
    scenes = [scene.read() for split in SUBSETS for scene in listed_scenes(dataset, split)]
    return {image_key(record.rgb): record.oracle.placement for record in scenes}


def test_a_fixed_random_policy_scores_the_same_through_the_env_and_the_harness(smoke_dataset):
    oracles = oracles_by_image(smoke_dataset)
    policy = MixedPolicy(oracles)
    through_env = {}
    for split in SUBSETS:
        env = gymnasium.make(ENV_ID, dataset=smoke_dataset, split=split)
        for episode in range(len(listed_scenes(smoke_dataset, split))):
            observation, info = env.reset(seed=episode)
            through_env[info["scene"]] = env.step(policy.place(observation))[1]
    results = evaluate_policy(MixedPolicy(oracles), smoke_dataset, SETTINGS, label="Mixed")
    (entry,) = results["evaluations"]
    through_harness = {s["id"]: float(s["success"]) for subset in SUBSETS for s in entry["subsets"][subset]["scenes"]}
    assert through_harness == through_env
    assert set(through_env.values()) == {0.0, 1.0}
    assert entry["method"] == "test_policy_evaluation:MixedPolicy" and "| Mixed |" in table_one(results)
    failures = [s["failure"] for s in entry["subsets"]["seen"]["scenes"] if s["failure"]]
    assert failures and all("finite" in failure for failure in failures)  # the NaN placements


def test_a_method_object_runs_as_registered_methods_do(smoke_dataset):
    results = evaluate_policy(eval_methods.OracleMethod(smoke_dataset), smoke_dataset, SETTINGS)
    (entry,) = results["evaluations"]
    assert entry["label"] == "eval_methods:OracleMethod" and entry["description"] == {"dataset": str(smoke_dataset)}
    assert all(entry["subsets"][subset]["aggregate"]["overall"]["success"] == 1.0 for subset in SUBSETS)


def test_a_method_named_by_reference_runs_in_its_own_process_as_in_this_one(smoke_dataset):
    """Its keys, outputs and the failures of the scenes it raises on are the same whichever process runs it."""

    def scenes(policy) -> list:
        (entry,) = evaluate_policy(policy, smoke_dataset, SETTINGS)["evaluations"]
        return [
            (s["mode"], s["sample_success"], s["failure"])
            for subset in SUBSETS
            for s in entry["subsets"][subset]["scenes"]
        ]

    for name in ("RandomMethod", "FlakyMethod"):
        hosted, here = scenes(f"eval_methods:{name}"), scenes(getattr(eval_methods, name)())
        assert hosted == here, name
    assert {failure is None for _, _, failure in hosted} == {True, False}  # FlakyMethod's odd scenes


STUCK_POLICY = '''
import os, signal, time
from pathlib import Path


def place(observation):
    """Stuck where no signal reaches it on its first call, its process gone on the second, then the centre."""
    calls = Path(os.environ["OCPLACE_TEST_POLICY_CALLS"])
    count = len(calls.read_text().split()) if calls.exists() else 0
    calls.write_text(calls.read_text() + f" {os.getpid()}" if count else str(os.getpid()))
    if count == 0:
        signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGALRM, signal.SIGINT, signal.SIGTERM})
        time.sleep(3600)
    if count == 1:
        os._exit(7)
    return (0.0, 0.0)
'''


def test_a_policy_stuck_in_its_process_or_dying_fails_its_scene_and_a_fresh_process_goes_on(
    smoke_dataset, tmp_path, monkeypatch
):
    """Issue 43's decision: past `--scene-timeout` the scene fails with `timeout` and the worker is replaced, even
    for a call no signal interrupts (native code)."""
    (tmp_path / "stuck_policy_of_the_host_test.py").write_text(STUCK_POLICY)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("OCPLACE_TEST_POLICY_CALLS", str(tmp_path / "calls"))
    settings = dataclasses.replace(SETTINGS, subsets=("seen",), limit=4)
    started = time.monotonic()
    results = evaluate_policy("stuck_policy_of_the_host_test:place", smoke_dataset, settings, scene_timeout_s=1.0)
    scenes = results["evaluations"][0]["subsets"]["seen"]["scenes"]
    assert time.monotonic() - started < 60
    assert "timeout: the policy took more than 1 s" in scenes[0]["failure"]
    assert "the policy's process ended (exit code 7)" in scenes[1]["failure"]
    assert [s["mode"] for s in scenes[2:]] == [[0.0, 0.0]] * 2
    pids = [int(pid) for pid in (tmp_path / "calls").read_text().split()]
    assert len(set(pids)) == 3  # a process per failure, and the third took the rest
    for pid in pids[:2]:
        assert not Path(f"/proc/{pid}").exists(), "a killed policy's process is still there"


CENTRE_POLICY = '''
def place(observation):
    """The table's centre, whatever the instruction says."""
    return (0.0, 0.0)
'''


def test_cli_evaluates_a_policy_module_and_reruns_it(smoke_dataset, tmp_path, monkeypatch, capsys):
    (tmp_path / "centre_policy_of_the_cli_test.py").write_text(CENTRE_POLICY)
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "path", list(sys.path))  # the command puts the current folder on it
    common = ["evaluate", "--dataset", str(smoke_dataset), "--subsets", "seen", "--physical", "0", "--no-progress"]
    common += ["--backbone", "none", "--limit", "4", "--out", "results.json"]
    assert main([*common, "--policy", "no_such_module_anywhere:place"]) == 2
    assert "cannot import the policy module" in capsys.readouterr().err
    assert main([*common, "--policy", "centre_policy_of_the_cli_test"]) == 2
    assert "MODULE:CALLABLE" in capsys.readouterr().err
    broken = {  # issue 43, defect 12: each was a raw traceback, exit 1
        "raising_policy_of_the_cli_test": ('raise RuntimeError("no GPU here")\n', "RuntimeError: no GPU here"),
        "syntax_policy_of_the_cli_test": ("def place(:\n", "SyntaxError"),
        "class_policy_of_the_cli_test": (
            "class Place:\n    def __init__(self):\n        raise ValueError('needs a model path')\n",
            "failed when made with no arguments (ValueError: needs a model path)",
        ),
    }
    for module, (source, message) in broken.items():
        (tmp_path / f"{module}.py").write_text(source)
        callable_name = "Place" if module.startswith("class") else "place"
        assert main([*common, "--policy", f"{module}:{callable_name}"]) == 2
        err = capsys.readouterr().err
        assert err.startswith("ocplace evaluate: error:") and message in err, err
    (tmp_path / "failing_policy_of_the_cli_test.py").write_text(
        "def place(observation):\n    raise ValueError('no model')\n"
    )
    assert main([*common, "--policy", "failing_policy_of_the_cli_test:place"]) == 1  # written, but it placed nothing
    assert "placed nothing: all 4 scenes failed, 4 of them with ValueError" in capsys.readouterr().err
    assert main([*common, "--policy", "centre_policy_of_the_cli_test:place", "--label", "Centre"]) == 0
    assert "| Centre |" in capsys.readouterr().out
    saved = read_results(tmp_path / "results.json")
    assert [e["method"] for e in saved["evaluations"]] == ["centre_policy_of_the_cli_test:place"]
    assert [s["mode"] for s in saved["evaluations"][0]["subsets"]["seen"]["scenes"]] == [[0.0, 0.0]] * 4
    assert main(["evaluate", "--rerun", "results.json", "--no-progress"]) == 2  # the file alone imports nothing
    assert "never makes ocplace import code: name each again with --policy" in capsys.readouterr().err
    assert main(["evaluate", "--rerun", "results.json", "--policy", "centre_policy_of_the_cli_test:place"]) == 0
    assert "reproduced exactly" in capsys.readouterr().out
    crafted = json.loads((tmp_path / "results.json").read_text())
    crafted["evaluations"][0]["method"] = "builtins:input"  # what a hostile file would name
    (tmp_path / "crafted.json").write_text(json.dumps(crafted))
    assert main(["evaluate", "--rerun", "crafted.json", "--no-progress"]) == 2
    assert "'builtins:input'" in capsys.readouterr().err


def test_a_policy_no_process_can_import_again_is_evaluated_and_its_rerun_refused(smoke_dataset, tmp_path, capsys):
    from ocplace.eval.table import write_outputs

    def place(observation):
        return (0.0, 0.0)

    settings = dataclasses.replace(SETTINGS, subsets=("seen",), limit=2)
    local_name = place.__qualname__  # test_....<locals>.place
    for module, qualname, message in (
        ("__main__", "place", "in a script run directly (__main__)"),
        (__name__, local_name, "inside a function"),
    ):
        place.__module__, place.__qualname__ = module, qualname
        results = evaluate_policy(place, smoke_dataset, settings)
        (entry,) = results["evaluations"]
        assert entry["method"] == f"{module}:{qualname}"
        assert [s["mode"] for s in entry["subsets"]["seen"]["scenes"]] == [[0.0, 0.0]] * 2
        path = tmp_path / f"{module}.json"
        write_outputs(results, path)
        capsys.readouterr()
        assert main(["evaluate", "--rerun", str(path), "--no-progress", "--trust-policy"]) == 2
        err = capsys.readouterr().err
        assert err.startswith(f"ocplace evaluate: error: the policy '{entry['method']}' was defined {message}"), err
        assert not path.with_name(path.stem + ".rerun.json").exists()


class _Unconvertible:
    def __array__(self, dtype=None, copy=None):
        raise RuntimeError("no array for you")


class _NoneMethod:
    def describe(self) -> dict:
        return {}

    def run(self, scenes, key):
        return [None for _ in scenes]


def test_a_policys_odd_answers_and_exits_are_failures_of_their_scenes(smoke_dataset):
    """Issue 43, defect 8: each of these aborted the whole evaluation (a traceback, or a silent exit 3)."""
    settings = dataclasses.replace(SETTINGS, subsets=("seen",), limit=2)
    policies = {
        "overflow": (lambda observation: (10**400, 0), "OverflowError"),
        "unconvertible": (lambda observation: _Unconvertible(), "no array for you"),
        "exit": (lambda observation: sys.exit(3), "SystemExit: 3"),
        "none": (_NoneMethod(), "NoneType, not a MethodOutput"),
    }
    for name, (policy, message) in policies.items():
        (entry,) = evaluate_policy(policy, smoke_dataset, settings, label=name)["evaluations"]
        scenes = entry["subsets"]["seen"]["scenes"]
        assert len(scenes) == 2 and all(not s["success"] and message in s["failure"] for s in scenes), (name, scenes)


class _SlowOnFirst:
    """Sleeps far past the deadline on its first scene (and swallows the first timeout), then answers at once."""

    def __init__(self):
        self.calls = 0

    def place(self, observation):
        self.calls += 1
        if self.calls == 1:
            try:
                time.sleep(30)
            except Exception:  # a policy that swallows the timeout still cannot hang the evaluation
                time.sleep(30)
        return (0.0, 0.0)


def test_a_scene_past_its_deadline_fails_as_a_timeout_and_the_rest_run(smoke_dataset):
    """Issue 43's decision: `--scene-timeout` (default 60 s) for anyone's policy."""
    settings = dataclasses.replace(SETTINGS, subsets=("seen",), limit=3)
    started = time.monotonic()
    (entry,) = evaluate_policy(_SlowOnFirst(), smoke_dataset, settings, scene_timeout_s=0.5)["evaluations"]
    scenes = entry["subsets"]["seen"]["scenes"]
    assert time.monotonic() - started < 20
    assert "timeout: the policy took more than 0.5 s" in scenes[0]["failure"]
    assert [s["mode"] for s in scenes[1:]] == [[0.0, 0.0]] * 2


def _blocks_after(text: str, marker: str) -> list[tuple[str, str]]:
    """(language, code) of the fenced blocks that follow `marker` in `text`, in order."""
    return re.findall(r"```(\w+)\n(.*?)```", text.split(marker, 1)[1], re.S)


@pytest.mark.slow
def test_the_your_own_policy_tutorial_runs_as_written(smoke_dataset, tmp_path, monkeypatch, capsys):
    """docs/evaluation.md's complete example, block by block: my_policy.py, its two commands, its Python (with
    the smoke dataset for DATA)."""
    text = (Path(__file__).resolve().parents[1] / "docs" / "evaluation.md").read_text()
    (module, shell, python) = _blocks_after(text, "A complete example:")[:3]
    assert [module[0], shell[0], python[0]] == ["python", "bash", "python"]
    (tmp_path / "my_policy.py").write_text(module[1])
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(tmp_path))
    for line in shell[1].strip().splitlines():
        argv = shlex.split(line.split("#")[0].replace("DATA", str(smoke_dataset)))
        assert argv[0] == "ocplace" and main(argv[1:]) == 0, line
    assert "reproduced exactly" in capsys.readouterr().out
    exec(compile(python[1].replace('"DATA"', repr(str(smoke_dataset))), "evaluation.md", "exec"), {})
    assert "| Farthest point |" in capsys.readouterr().out


def test_the_policys_process_is_as_wide_as_the_evaluations_jax_while_it_loads_and_first_answers(tmp_path, monkeypatch):
    """What JAX starts while the policy is imported, made or answers its first scene sizes itself to `jax_width`
    CPUs (as in the evaluation's worker); afterwards the pin is lifted."""
    import os

    from ocplace.methods.policy_host import PolicyHost

    (tmp_path / "width_policy_of_the_host_test.py").write_text(
        "import os\n\n\ndef place(observation):\n    return (len(os.sched_getaffinity(0)), 0.0)\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    host = PolicyHost("width_policy_of_the_host_test:place", jax_width=1)
    try:
        assert host.request(("place", {}), 10.0) == {"mode": [1.0, 0.0]}
        assert host.request(("place", {}), 10.0) == {"mode": [float(len(os.sched_getaffinity(0))), 0.0]}
    finally:
        assert host.stop() is not None and host.stop() is None  # stopped once


@pytest.mark.slow
def test_the_environment_listing_runs_as_written(smoke_dataset):
    """docs/evaluation.md's Gymnasium listing, with the names its comments point to (DIR: the smoke dataset)."""
    from ocplace.sim.dataset.config import make_config

    text = (Path(__file__).resolve().parents[1] / "docs" / "evaluation.md").read_text()
    ((language, block),) = _blocks_after(text, "### The Gymnasium environment")[:1]
    assert language == "python" and block.count("gymnasium.make") == 5
    namespace = {"gymnasium": gymnasium, "make_config": make_config, "DIR": str(smoke_dataset)}
    exec(compile(block, "evaluation.md", "exec"), namespace)
    vector = namespace["env"]
    observations, infos = vector.reset(seed=0)
    assert list(infos["scene"]) == ["seen-00000", "seen-00001"] and observations["rgb"].shape[0] == 2
    vector.close()
