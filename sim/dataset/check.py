"""Scoring the oracle on a whole dataset: the success metric and the optional physical check.

The metric is cheap and runs here. The physical check drops the held object in MuJoCo for every
scene, so its scenes go to the executor's workers in chunks; each worker compiles the arena once.
"""

from __future__ import annotations

import contextlib

from ocplace.runtime import Executor, ExecutorConfig, Task, map_tasks, open_executor
from ocplace.runtime.progress import progress_bar
from ocplace.sim.dataset.job import ListedScene, listed_scenes
from ocplace.sim.metric import placement_success

_ARENA: dict = {}  # per worker process: the compiled MuJoCo arena of one dataset's library
CHUNKS_PER_WORKER = 4  # small enough to balance the workers, large enough to amortise each task


def _arena(dataset_dir, cache: str | None):
    key = (str(dataset_dir), cache)
    if _ARENA.get("key") != key:
        from ocplace.sim.dataset.job import library_of_dataset
        from ocplace.sim.mujoco_backend import MujocoScenes

        _close_arena()
        _ARENA.update(key=key, arena=MujocoScenes.from_library(library_of_dataset(dataset_dir, cache)))
    return _ARENA["arena"]


def _close_arena() -> None:
    if "arena" in _ARENA:
        _ARENA.pop("arena").close()
        _ARENA.clear()


def physical_failures(scenes: list[ListedScene], dataset_dir, cache: str | None) -> list[str]:
    """The ids of the scenes whose oracle placement fails the physical drop check."""
    from ocplace.sim.physical import physical_check

    failures = []
    for listed in scenes:
        scene = listed.info()
        if not physical_check(_arena(dataset_dir, cache), scene, scene.true_placement()).success:
            failures.append(scene.id)
    return failures


def _physical_report(
    scenes: list[ListedScene], dataset_dir, executor: Executor, cache: str | None, progress: bool, desc: str
) -> list:
    size = max(1, -(-len(scenes) // (executor.capacity * CHUNKS_PER_WORKER)))
    chunks = [scenes[start : start + size] for start in range(0, len(scenes), size)]
    failures = []
    bar = progress_bar(total=len(scenes), desc=desc, enabled=progress)
    for index, failed in map_tasks(
        executor, [Task(physical_failures, (chunk, str(dataset_dir), cache)) for chunk in chunks]
    ):
        failures += failed
        bar.update(len(chunks[index]))
    bar.close()
    return sorted(failures)


def check_oracle(
    dataset_dir,
    splits: list[str],
    physical: bool = False,
    executor: Executor | None = None,
    cache: str | None = None,
    progress: bool = True,
) -> dict:
    """Per split: how many oracle placements pass the metric (and, optionally, the physical check)."""
    report = {}
    with contextlib.ExitStack() as stack:
        stack.callback(_close_arena)  # the one this process made, when tasks ran here
        if executor is None and physical:
            executor = stack.enter_context(open_executor(ExecutorConfig(workers=1)))
        for split in splits:
            scenes = listed_scenes(dataset_dir, split)
            metric_failures = []
            for listed in progress_bar(scenes, desc=f"oracle {split}", enabled=progress):
                scene = listed.info()
                if not placement_success(scene.true_placement()[None], scene.problem())[0]:
                    metric_failures.append(scene.id)
            report[split] = {
                "scenes": len(scenes),
                "metric_success": len(scenes) - len(metric_failures),
                "metric_failures": metric_failures,
            }
            if physical and executor is not None:  # opened above when none was given
                failed = _physical_report(scenes, dataset_dir, executor, cache, progress, f"physical {split}")
                report[split] |= {"physical_success": len(scenes) - len(failed), "physical_failures": failed}
    return report
