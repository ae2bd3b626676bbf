"""The executors: a local process pool, a local Ray instance and a two-node Ray cluster on this machine.

Each gives the same bytes: datasets, jitted JAX results and a reproduce's results.json. A Ray worker
killed mid-task has its task retried; an unreachable head fails with ClusterError; a command that
started Ray leaves no Ray process behind. JAX and dataset bits on every executor (with the two-node
cluster) and the reproduce runs are slow tests (`make test-all`), to keep the default suite under
15 minutes on 2 cores.
"""

import concurrent.futures
import contextlib
import dataclasses
import hashlib
import json
import logging
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

from ocplace.errors import ClusterError, ConfigError, DatasetError
from ocplace.runtime import ExecutorConfig, Task, map_tasks, open_executor
from ocplace.runtime.executor import run_task
from ocplace.runtime.graph import Node, run_graph
from ocplace.runtime.width import compiled_folder
from ocplace.sim.dataset import job
from ocplace.sim.dataset.config import make_config
from ocplace.sim.dataset.job import (
    DIE_AFTER_SCENES_ENV,
    DIE_ONCE_MARKER_ENV,
    generate_dataset,
    verify_dataset,
)

TINY = dataclasses.replace(make_config(train=6, test=1), splits=make_config(train=6, test=1).splits[:1])
LOCAL = ExecutorConfig(workers=2)
RAY = ExecutorConfig(kind="ray", workers=2)
TESTS = str(Path(__file__).resolve().parent)


def jitted_sum_digest(seed: int) -> str:
    """A jitted reduction, whose bits depend on the CPUs XLA's client was sized for."""
    import jax

    values = jax.random.normal(jax.random.key(seed), (512, 4096))
    return hashlib.sha256(np.asarray(jax.jit(lambda x: x.sum())(values)).tobytes()).hexdigest()


def worker_and_digest(seed: int) -> tuple[int, str]:
    """The process a task ran in, and its JAX width's bits."""
    return os.getpid(), jitted_sum_digest(seed)


def die_the_first_time(marker: Path) -> tuple[int, str]:
    """SIGKILLs its worker the first time (writing the worker's pid to `marker` first); then as worker_and_digest."""
    if not marker.exists():
        marker.write_text(str(os.getpid()))
        os.kill(os.getpid(), signal.SIGKILL)
    return worker_and_digest(0)


def in_a_fresh_process(task: Task):
    """`task` the way every pinned task ran before long-lived workers: pinned in a process of its own."""
    return in_a_fresh_interpreter(run_task, task)


def in_a_fresh_interpreter(fn, *args):
    """`fn(*args)` in a new Python process. A driver joins the two-node cluster from one: Ray (2.60) kills
    the actors a process creates on a joined cluster as out of scope once that process has run a local
    Ray instance, as earlier tests here do (a command runs one executor, so it never meets this)."""
    import multiprocessing

    with concurrent.futures.ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as fresh:
        return fresh.submit(fn, *args).result()


def digests_and_dataset(config: ExecutorConfig, digests: list[Task], out: Path) -> tuple[dict, dict]:
    """The digest tasks' results and TINY's train split (its files' hashes), made on `config`'s executor."""
    with open_executor(config) as executor:
        found = dict(map_tasks(executor, digests))
        return found, generate_dataset(out, TINY, executor=executor, progress=False)["files"]


def fail_with_dataset_error(message: str):
    raise DatasetError(message)


def add(*values):
    return sum(values)


@pytest.fixture(scope="module", autouse=True)
def workers_import_this_module():
    """Ray workers unpickle this module's task functions by name: put tests/ on their path."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("PYTHONPATH", os.pathsep.join(filter(None, [TESTS, os.environ.get("PYTHONPATH")])))
        yield


@pytest.fixture(scope="module")
def two_nodes(workers_import_this_module):
    """A Ray cluster of two nodes on this machine, one CPU each (short temp dir: socket paths < 107 chars)."""
    from ray.cluster_utils import Cluster

    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    temp_dir = tempfile.mkdtemp(prefix="ocray-", dir="/tmp")
    address_file = Path(tempfile.gettempdir()) / "ray" / "ray_current_cluster"  # Cluster writes it there
    address_file.parent.mkdir(exist_ok=True)
    had_address_file = address_file.exists()
    cluster = Cluster(
        initialize_head=True, head_node_args={"num_cpus": 1, "include_dashboard": False, "temp_dir": temp_dir}
    )
    cluster.add_node(num_cpus=1)
    cluster.wait_for_nodes()
    yield ExecutorConfig(kind="ray", address=cluster.address)
    cluster.shutdown()
    shutil.rmtree(temp_dir, ignore_errors=True)
    if not had_address_file:
        address_file.unlink(missing_ok=True)


@pytest.fixture(scope="module")
def reference(library, tmp_path_factory):
    """TINY's train split made by this process alone: the bytes every executor must reproduce."""
    return generate_dataset(tmp_path_factory.mktemp("reference"), TINY, progress=False)["files"]


def ray_processes() -> set[int]:
    """Live (not zombie) processes of a Ray instance: its GCS, raylet, agents and workers."""
    found = set()
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            command = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            state = (entry / "stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        if state != "Z" and ("ray::" in command or "raylet" in command or "gcs_server" in command):
            found.add(int(entry.name))
    return found


def test_graph_runs_a_node_after_its_inputs_and_skips_what_follows_a_failure():
    nodes = [
        Node("a", lambda done: Task(add, (1, 2))),
        Node("b", lambda done: Task(add, (done["a"], 10)), ("a",)),
        Node("bad", lambda done: Task(fail_with_dataset_error, ("broken on purpose",))),
        Node("after bad", lambda done: Task(add, (1,)), ("bad", "a")),
        Node("c", lambda done: Task(add, (done["a"], done["b"])), ("a", "b")),
    ]
    with open_executor(LOCAL) as executor:
        outcomes = run_graph(executor, nodes)
    assert {key: o.value for key, o in outcomes.items() if o.ok} == {"a": 3, "b": 13, "c": 16}
    assert isinstance(outcomes["bad"].error, DatasetError)
    assert outcomes["after bad"].skipped_because == "bad"
    with pytest.raises(ValueError, match="not listed before it"):
        run_graph(None, [Node("x", lambda done: Task(add), ("y",)), Node("y", lambda done: Task(add))])


def test_more_workers_than_the_machine_runs_are_clamped_with_a_warning(caplog):
    cpus = len(os.sched_getaffinity(0))
    with caplog.at_level(logging.WARNING), open_executor(ExecutorConfig(workers=cpus + 62)) as executor:
        pids = {pid for _, pid in map_tasks(executor, [Task(os.getpid) for _ in range(4 * cpus)])}
    assert executor.capacity <= cpus and len(pids) <= cpus
    assert f"--workers {cpus + 62} is more than this machine runs side by side ({cpus} CPUs; " in caplog.text
    assert f"using {executor.capacity} workers" in caplog.text


# Slow: the default suite's 15 min budget on 2 cores (docs/performance.md, session 12); the Ray command's end-to-end
# run, its reaping and its unreachable head stay in it
@pytest.mark.slow
def test_a_local_ray_instance_retries_a_killed_worker_and_reraises_task_errors(reference, tmp_path, monkeypatch):
    marker = tmp_path / "a-worker-died"
    with open_executor(RAY) as executor:
        with pytest.raises(DatasetError, match="broken on purpose"):  # a task's own error comes back as itself
            list(map_tasks(executor, [Task(fail_with_dataset_error, ("broken on purpose",))]))
        monkeypatch.setattr(job, "scenes_per_task", lambda scenes, workers: 3)  # tasks of 3 scenes
        monkeypatch.setenv(DIE_AFTER_SCENES_ENV, "2")  # SIGKILL after a worker's 2nd scene: mid-task
        monkeypatch.setenv(DIE_ONCE_MARKER_ENV, str(marker))  # ... in the first worker that gets there only
        files = generate_dataset(tmp_path / "data", TINY, executor=executor, progress=False)["files"]
    assert marker.exists(), "no worker was killed: the test proved nothing"
    assert files == reference  # the same bytes as this process alone made
    assert verify_dataset(tmp_path / "data") == []
    assert not list((tmp_path / "data" / "train").glob(".tmp-*"))


KILLED_DRIVER = """
import os, signal
from ocplace.runtime import ExecutorConfig, Task, map_tasks, open_executor
from ocplace.runtime.executor import run_task
with open_executor(ExecutorConfig(kind="ray", workers=1)) as executor:
    print(executor._temp_dir, list(map_tasks(executor, [Task(os.getpid)])), flush=True)
    os.kill(os.getpid(), signal.SIGKILL)
"""


def test_the_next_ray_start_reaps_what_a_killed_command_left():
    from ocplace.runtime.ray_executor import _processes_using

    killed = subprocess.run([sys.executable, "-c", KILLED_DRIVER], capture_output=True, text=True, timeout=300)
    assert killed.returncode == -9, killed.stderr
    folder = Path(killed.stdout.split()[0])
    left = _processes_using(folder)
    try:
        assert folder.is_dir() and left, "Ray left nothing behind: there is nothing to reap"
        with open_executor(RAY) as executor:  # the next start
            assert not folder.exists() and Path(executor._temp_dir).is_dir()
            assert dict(map_tasks(executor, [Task(add, (1, 2))])) == {0: 3}
        for pid in left:
            state = Path(f"/proc/{pid}/stat")
            assert not state.exists() or state.read_text().rsplit(")", 1)[1].split()[0] in "ZX"
    finally:
        for pid in left:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, 9)


def test_pinned_tasks_run_on_long_lived_workers_of_their_width_with_a_fresh_processs_bits(tmp_path, monkeypatch):
    monkeypatch.setenv("OCPLACE_CACHE", str(tmp_path))
    tasks = [Task(worker_and_digest, (0,), cpus=cpus, pinned=True) for cpus in (1, 1, 1, 2, 2)]
    fresh = {cpus: in_a_fresh_process(Task(jitted_sum_digest, (0,), cpus=cpus, pinned=True)) for cpus in (1, 2)}
    with open_executor(LOCAL) as pool:
        ran = dict(map_tasks(pool, tasks))
    workers = {cpus: {ran[i][0] for i, task in enumerate(tasks) if task.cpus == cpus} for cpus in (1, 2)}
    assert len(workers[1]) <= 2 and len(workers[2]) == 1 and not workers[1] & workers[2]  # 2 one-wide, 1 two-wide
    assert all(ran[i][1] == fresh[task.cpus] for i, task in enumerate(tasks)), "a reused worker gave other bits"


# Slow: the default suite's 15 min budget on 2 cores (docs/performance.md, session 12); the local pool's test
# of the same contract stays in it
@pytest.mark.slow
def test_pinned_tasks_on_ray_run_on_long_lived_actors_of_their_width_with_a_fresh_processs_bits(tmp_path, monkeypatch):
    monkeypatch.setenv("OCPLACE_CACHE", str(tmp_path))
    tasks = [Task(worker_and_digest, (0,), cpus=cpus, pinned=True) for cpus in (1, 1, 1, 2, 2)]
    fresh = {cpus: in_a_fresh_process(Task(jitted_sum_digest, (0,), cpus=cpus, pinned=True)) for cpus in (1, 2)}
    with open_executor(RAY) as executor:
        ran = dict(map_tasks(executor, tasks))  # more than the instance's 2 CPUs: the executor queues them
        # Idle actors hold their CPUs: an unpinned task still runs, once the idle two-wide actor is ended.
        assert dict(map_tasks(executor, [Task(add, (1, 2)), Task(add, (3, 4))])) == {0: 3, 1: 7}
    workers = {cpus: {ran[i][0] for i, task in enumerate(tasks) if task.cpus == cpus} for cpus in (1, 2)}
    assert len(workers[1]) <= 2 and len(workers[2]) == 1 and not workers[1] & workers[2]
    assert all(ran[i][1] == fresh[task.cpus] for i, task in enumerate(tasks)), "a reused actor gave other bits"


# Slow: the default suite's 15 min budget on 2 cores (docs/performance.md, session 12); the local pool's killed
# worker and Ray's retry of a killed worker mid-generation stay in it
@pytest.mark.slow
def test_a_killed_ray_actor_is_restarted_and_its_task_retried(tmp_path, monkeypatch):
    monkeypatch.setenv("OCPLACE_CACHE", str(tmp_path))
    marker = tmp_path / "killed-actor"
    with open_executor(RAY) as executor:
        worker, digest = dict(map_tasks(executor, [Task(die_the_first_time, (marker,), cpus=2, pinned=True)]))[0]
    assert marker.exists(), "no actor was killed: the test proved nothing"
    assert worker != int(marker.read_text())
    assert digest == in_a_fresh_process(Task(jitted_sum_digest, (0,), cpus=2, pinned=True))


def test_a_killed_worker_fails_its_task_and_is_replaced_by_a_pinned_one(tmp_path, monkeypatch):
    monkeypatch.setenv("OCPLACE_CACHE", str(tmp_path))
    marker = tmp_path / "killed-worker"
    task = Task(die_the_first_time, (marker,), cpus=2, pinned=True)
    with open_executor(LOCAL) as pool:
        with pytest.raises(ClusterError, match="a worker process died"):
            dict(map_tasks(pool, [task]))
        worker, digest = dict(map_tasks(pool, [task]))[0]  # the same task again, as rerunning the command would
    assert worker != int(marker.read_text())
    assert digest == in_a_fresh_process(Task(jitted_sum_digest, (0,), cpus=2, pinned=True))


# Slow: the default suite's 15 min budget on 2 cores (docs/performance.md, session 12); the pinned workers' bits test
# stays in it
@pytest.mark.slow
def test_new_workers_reuse_what_an_earlier_one_compiled_at_the_same_width(tmp_path, monkeypatch):
    monkeypatch.setenv("OCPLACE_CACHE", str(tmp_path))  # the pool's processes start after this
    task = Task(jitted_sum_digest, (0,), pinned=True)
    with open_executor(LOCAL) as pool:
        first = dict(map_tasks(pool, [task]))[0]
    compiled = {path: path.read_bytes() for path in compiled_folder(1).glob("*-atime")}
    assert compiled, "nothing was written to the compilation cache"
    with open_executor(LOCAL) as pool:  # new workers: the earlier one's in-memory executables went with it
        finished = dict(map_tasks(pool, [task, dataclasses.replace(task, cpus=2)]))  # in the order they ended
        again, wider = finished[0], finished[1]
    assert again == first
    assert all(path.read_bytes() != used for path, used in compiled.items()), "the second task compiled again"
    if len(os.sched_getaffinity(0)) > 1:
        assert list(compiled_folder(2).glob("*-cache")) and wider != first  # each width compiles its own


# Slow (`make test-all`): a cluster start and four fresh processes per executor, over a minute.
@pytest.mark.slow
def test_jax_and_datasets_give_the_same_bits_on_every_executor(reference, two_nodes, tmp_path):
    digests = [Task(jitted_sum_digest, (seed,), pinned=True) for seed in range(2)]
    with open_executor(ExecutorConfig(workers=1)) as one:
        expected = dict(map_tasks(one, digests))
    with open_executor(LOCAL) as pool:  # the control: a reused process is not pinned and sees every CPU
        unpinned = dict(map_tasks(pool, [dataclasses.replace(task, pinned=False) for task in digests]))
        assert dict(map_tasks(pool, digests)) == expected  # the pool's dataset bytes: test_dataset.py
    if len(os.sched_getaffinity(0)) > 1:
        assert unpinned != expected, "JAX gives the same bits on 1 and 2 CPUs here: the pin is not tested"
    for name, config in {"ray": RAY, "cluster": two_nodes}.items():
        found, files = in_a_fresh_interpreter(digests_and_dataset, config, digests, tmp_path / name)
        assert found == expected, name
        assert files == reference, name
        assert verify_dataset(tmp_path / name) == []


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def test_an_unreachable_head_fails_with_a_typed_error(tmp_path):
    command = [sys.executable, "-m", "ocplace.cli", "generate", "--out", str(tmp_path / "d"), "--smoke"]
    closed = subprocess.run(
        [*command, "--ray-address", f"127.0.0.1:{_free_port()}"], capture_output=True, text=True, timeout=120
    )
    assert closed.returncode == 2 and "cannot reach the Ray head" in closed.stderr, closed.stderr
    with socket.socket() as silent:  # accepts connections, never speaks Ray
        silent.bind(("127.0.0.1", 0))
        silent.listen()
        address = f"127.0.0.1:{silent.getsockname()[1]}"
        silent_head = ExecutorConfig(kind="ray", address=address, connect_timeout_s=5)
        with pytest.raises(ClusterError, match=f"the Ray head at {address} did not answer"), open_executor(silent_head):
            pass
    with (
        pytest.raises(ConfigError, match="is not auto, HOST:PORT"),
        open_executor(ExecutorConfig("ray", 0, "nowhere")),
    ):
        pass


def test_a_ray_command_checks_physically_and_leaves_no_ray_process(smoke_dataset):
    from ocplace.sim.dataset.check import check_oracle

    before = ray_processes()
    command = [sys.executable, "-m", "ocplace.cli", "dataset", "check", str(smoke_dataset), "--split", "seen"]
    on_ray = subprocess.run(
        [*command, "--physical", "--ray", "--workers", "2"], capture_output=True, text=True, timeout=600
    )
    here = check_oracle(smoke_dataset, ["seen"], physical=True, progress=False)["seen"]
    assert on_ray.returncode == 0, on_ray.stderr
    assert f"seen: metric {here['metric_success']}/8, physical {here['physical_success']}/8" in on_ray.stdout
    assert ray_processes() <= before


def reproduce_oracle_and_random(config, out: Path) -> dict:
    """The results.json of the pipeline on the oracle (it trains) and random (seeds differ) methods."""
    import eval_methods

    from ocplace.experiments import pipeline

    specs = {name: eval_methods.SPECS[name] for name in ("oracle", "random")}
    summary = pipeline.run_pipeline(config, out, specs=specs, command=["pytest"])
    assert summary.errors == []
    return json.loads(summary.results_path.read_text())


# Slow (`make test-all`): each run starts a process per training and evaluation, a minute per executor.
@pytest.mark.slow
@pytest.mark.parametrize("seeds, where", [(1, "ray"), (2, "two_nodes")])
def test_reproduce_on_ray_writes_the_same_results(
    seeds,
    where,
    request,
    smoke_dataset,
    tiny_backbone_spec,
    library,
    tmp_path,  # library: built in the cache
):

    from ocplace import configs
    from ocplace.eval import results
    from ocplace.experiments import pipeline

    smoke = configs.get("smoke")
    experiment = dataclasses.replace(
        smoke,
        dataset=dataclasses.replace(smoke.dataset, physical_scenes=0),
        evaluation=dataclasses.replace(smoke.evaluation, seeds=seeds, subsets=("seen",), fraction_methods=()),
    )
    elsewhere = RAY if where == "ray" else request.getfixturevalue(where)
    configs_by_name = {
        name: pipeline.PipelineConfig(
            experiment, backbone=tiny_backbone_spec, dataset=smoke_dataset, executor=executor, progress=False
        )
        for name, executor in {"local": LOCAL, "ray": elsewhere}.items()
    }
    local = reproduce_oracle_and_random(configs_by_name["local"], tmp_path / "local")
    ray = in_a_fresh_interpreter(reproduce_oracle_and_random, configs_by_name["ray"], tmp_path / "ray")
    specs = ("oracle", "random")
    assert results.compare(local, ray) == []
    repeats = [f"~seed{seed}" for seed in range(1, seeds)]
    assert [e["key"] for e in ray["evaluations"]] == [f"{name}{r}" for name in specs for r in ["", *repeats]]
    assert [s["name"] for s in local["pipeline"]["steps"]] == [s["name"] for s in ray["pipeline"]["steps"]]
    assert local["pipeline"]["config"] == ray["pipeline"]["config"]
    if seeds > 1:
        table = (tmp_path / "ray" / "results.md").read_text()
        random_rows = [line for line in table.splitlines() if line.startswith("| Uniform random |")]
        assert f"(mean ± standard deviation over {seeds} seeds)" in table and " ± " in random_rows[0]
