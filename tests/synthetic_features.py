"""Synthetic cached features with a known answer, for tests and benchmarks.

Each of `num_classes` object classes (class 0 is the table) has an image prototype and an
unrelated text prototype, so zero-shot similarity is at chance and the adapters must learn the
pairing; the problem is separable because every token is its prototype plus small noise.
"""

from __future__ import annotations

import numpy as np

from ocplace.models.backbone import PromptConfig
from ocplace.models.features import FeatureInfo, Features, FeaturizeConfig


def _unit(x: np.ndarray) -> np.ndarray:
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


def synthetic_features(
    num_scenes: int,
    dim: int,
    seed: int = 0,
    num_classes: int = 8,
    noise: float = 0.05,
    max_objects: int = 5,
    max_tuples: int = 2,
    logit_scale: float = 100.0,
) -> Features:
    rng = np.random.default_rng(seed)
    image_protos = _unit(rng.normal(size=(num_classes, dim)))
    text_protos = _unit(rng.normal(size=(num_classes, dim)))
    max_tokens = max_objects + 1
    visual = np.zeros((num_scenes, max_tokens, dim), np.float32)
    visual_mask = np.zeros((num_scenes, max_tokens), bool)
    text = np.zeros((num_scenes, max_tuples, dim), np.float32)
    text_mask = np.zeros((num_scenes, max_tuples), bool)
    targets = np.zeros((num_scenes, max_tuples), np.int32)
    for scene in range(num_scenes):
        count = int(rng.integers(1, max_objects + 1))
        classes = np.append(rng.choice(np.arange(1, num_classes), size=count, replace=False), 0)  # table last
        visual[scene, : count + 1] = _unit(image_protos[classes] + noise * rng.normal(size=(count + 1, dim)))
        visual_mask[scene, : count + 1] = True
        num_tuples = int(rng.integers(1, max_tuples + 1))
        tokens = rng.choice(count + 1, size=num_tuples, replace=False)
        text[scene, :num_tuples] = _unit(text_protos[classes[tokens]] + noise * rng.normal(size=(num_tuples, dim)))
        text_mask[scene, :num_tuples] = True
        targets[scene, :num_tuples] = tokens
    info = FeatureInfo(
        key=f"synthetic-{num_scenes}-{dim}-{seed}-{num_classes}-{noise}",
        backbone_fingerprint="synthetic",
        dataset_hash="synthetic",
        config=FeaturizeConfig(max_objects, max_tuples, prompt=PromptConfig()),
        logit_scale=logit_scale,
        dim=dim,
    )
    return Features(
        visual,
        visual_mask,
        text,
        text_mask,
        targets,
        scene_ids=tuple(f"s{i:05d}" for i in range(num_scenes)),
        phrases=tuple(("synthetic",) * int(m.sum()) for m in text_mask),
        info=info,
    )
