"""Scoring the oracle on a whole dataset: the success metric and the optional physical check."""

from __future__ import annotations

from tqdm import tqdm

from ocplace.sim.dataset.job import scene_dirs
from ocplace.sim.dataset.records import SceneInfo, read_meta
from ocplace.sim.metric import placement_success
from ocplace.sim.mujoco_backend import MujocoScenes
from ocplace.sim.physical import physical_check


def check_oracle(dataset_dir, splits: list[str], library=None, physical: bool = False, progress: bool = True) -> dict:
    """Per split: how many oracle placements pass the metric (and, optionally, the physical check)."""
    report = {}
    arena = MujocoScenes.from_library(library) if physical else None
    try:
        for split in splits:
            dirs = scene_dirs(dataset_dir, split)
            metric_failures, physical_failures = [], []
            for scene_dir in tqdm(dirs, desc=f"oracle {split}", disable=not progress):
                scene = SceneInfo(read_meta(scene_dir))
                placement = scene.oracle.placement
                if not placement_success(placement[None], scene.problem())[0]:
                    metric_failures.append(scene.id)
                if arena is not None and not physical_check(arena, scene, placement).success:
                    physical_failures.append(scene.id)
            report[split] = {
                "scenes": len(dirs),
                "metric_success": len(dirs) - len(metric_failures),
                "metric_failures": metric_failures,
            }
            if arena is not None:
                report[split] |= {
                    "physical_success": len(dirs) - len(physical_failures),
                    "physical_failures": physical_failures,
                }
    finally:
        if arena is not None:
            arena.close()
    return report
