"""The category-held-out validation split pretraining choices are made on: whole corpus categories
(head-noun groups naming no benchmark object or primitive, `RenderConfig.validation_share` of them by a
seeded hash) held out of pretraining, rendered as benchmark-like scenes, and a zero-shot grounding
score on them: how well the backbone reaches categories it never saw.

Scenes hold five held-out models (at most `validation_cap` per category) dropped on a seen table, as the
benchmark drops its objects; each visible model is a reference ("a photo of a teapot."), grounded among
the scene's crops (cut as the pipeline cuts them) by cosine similarity. A prediction is right when the
chosen crop's model has the reference's name. No benchmark object, test subset or test texture is involved.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from pathlib import Path

import numpy as np

from ocplace.errors import SceneError, TrainingError
from ocplace.models.backbone import Backbone, PromptConfig
from ocplace.models.offline_recipes import RenderConfig
from ocplace.paths import atomic_path, corpus_cache
from ocplace.sim.boxes import boxes_from_segmentation, square_crop
from ocplace.sim.corpus.build import Corpus
from ocplace.sim.scene import sample_scene_spec, split_pools
from ocplace.train.pretrain.pool import validation_scene_assets

SCENES = 100
OBJECTS_PER_SCENE = 5
VALIDATION_DIR = "validation"


@dataclasses.dataclass(frozen=True)
class ValidationScenes:
    """`crops` uint8 `(M, S, S, 3)` of the visible held-out models, `names` `(M,)` their names,
    `scenes` int32 `(M,)` the scene of each crop."""

    crops: np.ndarray
    names: np.ndarray
    scenes: np.ndarray

    def save(self, path: Path) -> None:
        with atomic_path(path) as tmp, open(tmp, "wb") as handle:
            np.savez(handle, crops=self.crops, names=self.names, scenes=self.scenes)

    @classmethod
    def load(cls, path: Path) -> ValidationScenes:
        with np.load(path, allow_pickle=False) as arrays:
            return cls(arrays["crops"], arrays["names"], arrays["scenes"])


def _cache_path(assets, config: RenderConfig, count: int) -> Path:
    identity = json.dumps(
        [[a.name, str(a.directory.name)] for a in assets]
        + [config.crop_size, config.padding, config.seed, count, OBJECTS_PER_SCENE],
        sort_keys=True,
    )
    return corpus_cache() / VALIDATION_DIR / f"{hashlib.sha256(identity.encode()).hexdigest()[:16]}.npz"


def validation_scenes(library, corpus: Corpus, config: RenderConfig, count: int = SCENES) -> ValidationScenes:
    """The validation scenes of `config`'s held-out categories, rendered once and cached under the corpus."""
    assets = validation_scene_assets(corpus, library, config)
    if len(assets) < OBJECTS_PER_SCENE:
        raise TrainingError(
            f"only {len(assets)} corpus models are held out for validation; raise validation_share above "
            f"{config.validation_share}"
        )
    path = _cache_path(assets, config, count)
    if path.is_file():
        return ValidationScenes.load(path)
    from ocplace.sim.mujoco_backend import MujocoScenes

    _, textures = split_pools(library, "seen")
    crops, names, scenes = [], [], []
    with MujocoScenes(list(assets), {t: library.textures[t].path for t in textures}) as arena:
        for index in range(count):
            rng = np.random.default_rng([config.seed, index, 7])
            spec = sample_scene_spec(rng, [a.name for a in assets], textures, num_objects=OBJECTS_PER_SCENE)
            try:
                scene = arena.build(spec)
            except SceneError:
                continue
            boxes = boxes_from_segmentation(scene.segmentation)
            for object_id, box in zip(boxes.object_ids, boxes.boxes, strict=True):
                crops.append(square_crop(scene.rgb, box, config.padding, size=config.crop_size))
                names.append(arena.objects[spec.objects[int(object_id) - 1]].human_name)
                scenes.append(index)
    result = ValidationScenes(np.stack(crops), np.array(names), np.array(scenes, np.int32))
    result.save(path)
    return result


def validation_grounding(backbone: Backbone, scenes: ValidationScenes, prompt: PromptConfig = PromptConfig()) -> dict:
    """Zero-shot grounding top-1 of every held-out reference among its scene's crops, and crop-to-name
    retrieval top-1 among all held-out names."""
    visual = backbone.encode_images(scenes.crops)
    vocabulary = sorted(set(scenes.names.tolist()))
    texts = backbone.encode_texts([prompt.text_for(name, plural=False) for name in vocabulary])  # as recorded
    name_index = np.array([vocabulary.index(name) for name in scenes.names])
    similarity = visual @ texts.T  # (M, names)
    correct, chance = [], []
    for scene in np.unique(scenes.scenes):
        members = np.flatnonzero(scenes.scenes == scene)
        scores = similarity[members][:, name_index[members]]  # crop x reference
        chosen = members[np.argmax(scores, axis=0)]
        correct += list(scenes.names[chosen] == scenes.names[members])
        chance += [np.mean(scenes.names[members] == scenes.names[m]) for m in members]
    return {
        "grounding_top1": float(np.mean(correct)),
        "references": len(correct),
        "chance": float(np.mean(chance)),
        "retrieval_top1": float(np.mean(np.argmax(similarity, axis=1) == name_index)),
        "names": len(vocabulary),
        "scenes": int(len(np.unique(scenes.scenes))),
    }
