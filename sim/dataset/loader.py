"""Reading a dataset split for models: per-scene examples and padded numpy batches."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from ocplace.sim.boxes import square_crop
from ocplace.sim.dataset.job import listed_scenes
from ocplace.sim.dataset.records import SceneRecord
from ocplace.vocabulary import MAX_PARSED_TUPLES

CROP_SIZE = 224
MAX_BOXES = 5


@dataclasses.dataclass(frozen=True)
class SceneExample:
    """What the grounding model sees of one scene."""

    scene_id: str
    crops: np.ndarray  # (N, S, S, 3) uint8 square object crops, in box order
    workspace: np.ndarray  # (S, S, 3) uint8 whole image, letterboxed; visual token N (the table)
    texts: tuple[str, ...]  # one reference phrase per tuple ("table" for the table)
    targets: np.ndarray  # (L,) int32 index of each tuple's reference among the N + 1 tokens
    box_object_ids: np.ndarray  # (N,) int32 segmentation id of each crop's object


def letterbox(image: np.ndarray, size: int) -> np.ndarray:
    """`(size, size, 3)`: the image scaled to fit, centred, padded with its border pixels."""
    height, width = image.shape[:2]
    side = max(height, width)
    top, left = (side - height) // 2, (side - width) // 2
    square = cv2.copyMakeBorder(image, top, side - height - top, left, side - width - left, cv2.BORDER_REPLICATE)
    return cv2.resize(square, (size, size), interpolation=cv2.INTER_AREA)


def example_from_record(record: SceneRecord, crop_size: int = CROP_SIZE) -> SceneExample:
    boxes = record.boxes
    crops = (
        np.stack([square_crop(record.rgb, box, size=crop_size) for box in boxes.boxes])
        if len(boxes)
        else np.zeros((0, crop_size, crop_size, 3), np.uint8)
    )
    tuples = record.true_tuples()
    return SceneExample(
        scene_id=record.id,
        crops=crops,
        workspace=letterbox(record.rgb, crop_size),
        texts=tuple(t.reference_name for t in tuples),
        targets=np.array([t.token_index for t in tuples], np.int32),
        box_object_ids=boxes.object_ids,
    )


def iter_examples(dataset_dir: str | Path, split: str, crop_size: int = CROP_SIZE) -> Iterator[SceneExample]:
    """Every scene of `split` that the manifest lists, in id order, each checked against its hashes there."""
    for scene in listed_scenes(dataset_dir, split):
        yield example_from_record(scene.read(), crop_size)


def collate(examples: list[SceneExample], max_boxes: int = MAX_BOXES, max_tuples: int = MAX_PARSED_TUPLES) -> dict:
    """Pads examples into one batch of numpy arrays.

    crops (B, max_boxes, S, S, 3), crop_mask (B, max_boxes), box_object_ids (B, max_boxes),
    workspace (B, S, S, 3), targets (B, max_tuples), tuple_mask (B, max_tuples). A target indexes
    the padded token axis: crops 0..max_boxes-1, then the workspace at index `num_boxes`.
    """
    size = examples[0].workspace.shape[0]
    batch = len(examples)
    crops = np.zeros((batch, max_boxes, size, size, 3), np.uint8)
    crop_mask = np.zeros((batch, max_boxes), bool)
    box_ids = np.zeros((batch, max_boxes), np.int32)
    targets = np.zeros((batch, max_tuples), np.int32)
    tuple_mask = np.zeros((batch, max_tuples), bool)
    for row, example in enumerate(examples):
        count = len(example.crops)
        crops[row, :count] = example.crops
        crop_mask[row, :count] = True
        box_ids[row, :count] = example.box_object_ids
        targets[row, : len(example.targets)] = example.targets
        tuple_mask[row, : len(example.targets)] = True
    return {
        "scene_ids": [example.scene_id for example in examples],
        "crops": crops,
        "crop_mask": crop_mask,
        "box_object_ids": box_ids,
        "workspace": np.stack([example.workspace for example in examples]),
        "num_boxes": crop_mask.sum(axis=1).astype(np.int32),
        "targets": targets,
        "tuple_mask": tuple_mask,
        "texts": [example.texts for example in examples],
    }


def batches(
    dataset_dir: str | Path, split: str, batch_size: int, crop_size: int = CROP_SIZE, shuffle_seed: int | None = None
) -> Iterator[dict]:
    """Padded batches of `split`; with `shuffle_seed`, scenes in a seeded random order."""
    scenes = listed_scenes(dataset_dir, split)
    if shuffle_seed is not None:
        scenes = [scenes[i] for i in np.random.default_rng(shuffle_seed).permutation(len(scenes))]
    for start in range(0, len(scenes), batch_size):
        yield collate([example_from_record(s.read(), crop_size) for s in scenes[start : start + batch_size]])
