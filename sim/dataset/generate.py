"""Generating dataset scenes: drop objects, pick solvable references and relations, write records.

A scene depends only on (dataset seed, split, index), never on which worker made it or in which
order, so the same seed gives the same bytes with any number of workers and across resumed runs.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np

from ocplace import serial
from ocplace.errors import SceneError, UnsolvableScene
from ocplace.sim import relations
from ocplace.sim.boxes import boxes_from_segmentation
from ocplace.sim.dataset.config import LEVEL_REFERENCES, DatasetConfig, SplitConfig, split_stream
from ocplace.sim.dataset.records import SCHEMA_VERSION, encode_images, scene_files
from ocplace.sim.language import TABLE_NAME, ReferenceTuple, render_instruction
from ocplace.sim.metric import DEFAULT_GRID, GroundedTuple, encode_problem, feasible_grid, oracle_placement
from ocplace.sim.mujoco_backend import MujocoScenes
from ocplace.sim.scene import RenderedScene, sample_mixed_spec, sample_scene_spec, split_pools


def scene_id(split: str, index: int) -> str:
    return f"{split}-{index:05d}"


def level_schedule(split: SplitConfig, seed: int) -> list[str]:
    """The level of every index of `split`, in a seeded order so any prefix mixes the levels."""
    levels = [level for level, count in split.levels for _ in range(count)]
    order = np.random.default_rng([seed, split_stream(split.name), 7]).permutation(len(levels))
    return [levels[i] for i in order]


def _half_extents(library, name: str) -> list[float]:
    extents = library.get(name).extents
    return [extents[0] / 2.0, extents[1] / 2.0]


def _draw_tuples(rng: np.random.Generator, level: str, visible_ids: list[int]) -> list[tuple[int, str]]:
    """`(reference object id, canonical relation)` per tuple; object id 0 is the table."""
    if level == "table":
        return [(0, relations.RELATION_NAMES[rng.integers(len(relations.RELATION_NAMES))])]
    chosen = rng.choice(visible_ids, size=LEVEL_REFERENCES[level], replace=False)
    names = relations.OBJECT_RELATION_NAMES
    return [(int(object_id), names[rng.integers(len(names))]) for object_id in chosen]


class SceneGenerator:
    """Makes the records of one dataset; one per worker process (it owns a MuJoCo arena)."""

    def __init__(self, library, config: DatasetConfig):
        self.library = library
        self.config = config
        self.arena = MujocoScenes.from_library(library)

    def close(self) -> None:
        self.arena.close()

    def make(self, split_name: str, index: int, level: str) -> dict[str, bytes]:
        """The files of scene `index` of `split_name`, by file name."""
        meta, scene = self.make_scene(split_name, index, level)
        images = encode_images(scene.rgb, scene.depth, scene.segmentation, self.config.png_compression)
        return scene_files(meta, images)

    def make_scene(self, split_name: str, index: int, level: str) -> tuple[dict, RenderedScene]:
        """The scene.json content and the rendered scene of scene `index` of `split_name`, before encoding."""
        split = self.config.split(split_name)
        rng = np.random.default_rng([self.config.seed, split_stream(split_name), index])
        objects, textures = split_pools(self.library, split.objects)
        _, texture_pool = split_pools(self.library, split.textures)
        distractors = self.library.names(self.config.distractors) if self.config.distractors else []
        resamples = {"scenes": 0, "relations": 0}
        for _ in range(self.config.max_scene_attempts):
            if distractors:
                spec = sample_mixed_spec(rng, objects, distractors, texture_pool or textures)
            else:
                spec = sample_scene_spec(rng, objects, texture_pool or textures)
            try:
                scene = self.arena.build(spec)
            except SceneError:  # objects kept rolling off the table: draw another set of objects
                resamples["scenes"] += 1
                continue
            chosen = self._choose_tuples(rng, scene, level, resamples, set(objects))
            if chosen is not None:
                tuples, feasible = chosen
                return self._meta(split, index, level, rng, scene, tuples, feasible, resamples), scene
            resamples["scenes"] += 1
        raise UnsolvableScene(
            f"{scene_id(split_name, index)}: no solvable {level} instruction in {self.config.max_scene_attempts} scenes"
        )

    def _choose_tuples(self, rng, scene: RenderedScene, level: str, resamples: dict, referable: set[str]):
        """`(tuples, feasible grid)` referring only to `referable` objects (the split's own, never a distractor)."""
        boxes = boxes_from_segmentation(scene.segmentation)
        names = {obj.object_id: obj.name for obj in scene.objects}
        visible = [i for i in boxes.object_ids.tolist() if names[i] in referable]
        if len(visible) < LEVEL_REFERENCES[level]:
            return None
        aabbs = np.array([obj.aabb[:, :2] for obj in scene.objects])
        half = _half_extents(self.library, scene.spec.held_object)
        for _ in range(self.config.max_relation_attempts):
            tuples = _draw_tuples(rng, level, visible)
            grounded = [GroundedTuple(rel, None if ref == 0 else aabbs[ref - 1]) for ref, rel in tuples]
            feasible = feasible_grid(encode_problem(grounded, aabbs, half))
            if feasible.any():
                return tuples, feasible
            resamples["relations"] += 1
        return None

    def _meta(
        self,
        split: SplitConfig,
        index: int,
        level: str,
        rng,
        scene: RenderedScene,
        tuples: list[tuple[int, str]],
        feasible: np.ndarray,
        resamples: dict,
    ) -> dict:
        library, spec = self.library, scene.spec
        boxes = boxes_from_segmentation(scene.segmentation)
        box_ids = boxes.object_ids.tolist()
        human = {obj.object_id: library.get(obj.name).human_name for obj in scene.objects}
        reference_tuples = [
            ReferenceTuple(TABLE_NAME if ref == 0 else human[ref], rel, ref == 0) for ref, rel in tuples
        ]
        instruction = render_instruction(reference_tuples, split.instructions, rng)
        held = library.get(spec.held_object)
        return {
            "schema_version": SCHEMA_VERSION,
            "id": scene_id(split.name, index),
            "split": split.name,
            "index": index,
            "level": level,
            "instruction": instruction,
            "instruction_style": split.instructions,
            "tuples": [
                {
                    "reference_object_id": ref,
                    "reference_name": item.name,
                    "relation": rel,
                    "token_index": len(box_ids) if ref == 0 else box_ids.index(ref),
                }
                for (ref, rel), item in zip(tuples, reference_tuples, strict=True)
            ],
            "held_object": {
                "name": held.name,
                "human_name": held.human_name,
                "extents": list(held.extents),
                "footprint_half_extents": _half_extents(library, held.name),
            },
            "table_texture": spec.table_texture,
            "spec": serial.to_dict(spec),
            "objects": [
                {
                    "object_id": obj.object_id,
                    "name": obj.name,
                    "human_name": human[obj.object_id],
                    "asset": library.get(obj.name).source,
                    "position": obj.position.tolist(),
                    "quaternion": obj.quaternion.tolist(),
                    "aabb": obj.aabb.tolist(),
                }
                for obj in scene.objects
            ],
            "boxes": [
                {"object_id": int(i), "box": b.tolist(), "pixels": int(c)}
                for i, b, c in zip(boxes.object_ids, boxes.boxes, boxes.pixel_counts, strict=True)
            ],
            "camera": self.arena.config.camera.to_json(),
            "oracle": {
                "placement": oracle_placement(feasible).tolist(),
                "feasible_cells": int(feasible.sum()),
                "grid_resolution": DEFAULT_GRID.resolution,
            },
            "resamples": resamples,
            "settle_steps": scene.settle_steps,
        }


def describe(config: DatasetConfig) -> dict:
    """The generator configuration as stored in (and read back from) the dataset's `dataset.json`; the benchmark's
    datasets leave out the catalogue fields, so datasets made before them keep their identity."""
    described = json.loads(json.dumps(dataclasses.asdict(config)))
    return {key: value for key, value in described.items() if key not in _OWN_FIELDS or value is not None}


_OWN_FIELDS = ("catalogue", "distractors")
