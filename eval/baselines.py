"""The two competing approaches of Table I: Raw Image Grids and CLIPort-Place (docs/baselines.md).

Both read only what eval/api.py allows: RGB-D, the record's boxes with the AABBs of those objects,
the camera, the instruction and the held object's footprint; never the tuples or the oracle.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from collections.abc import Sequence
from pathlib import Path

import jax
import numpy as np

from ocplace.errors import OcplaceError, TrainingError
from ocplace.eval.api import LoadContext, MethodOutput, MethodSpec, TrainContext
from ocplace.models.baselines import cliport, grids
from ocplace.models.baselines.common import free_grid, top_down_camera
from ocplace.models.parsing.types import as_pairs, parse_note
from ocplace.paths import atomic_path, baselines_cache
from ocplace.sim.dataset.records import SceneRecord

SCENES_PER_BATCH = 8  # CLIPort scenes per network call (a fixed shape: one compilation)


def _load_backbone(spec: str, run_meta: dict, name: str):
    from ocplace.models.backbone import load_backbone

    backbone = load_backbone(spec)
    if backbone.fingerprint != run_meta["backbone_fingerprint"]:
        raise TrainingError(
            f"the {name} run was trained with another backbone (fingerprint "
            f"{run_meta['backbone_fingerprint'][:12]}, loaded {backbone.fingerprint[:12]}); "
            "evaluate with the backbone it was trained with, or retrain"
        )
    return backbone


def _failure(error: Exception) -> MethodOutput:
    return MethodOutput(mode=None, samples=None, failure=f"{type(error).__name__}: {error}")


def _describe(name: str, run_meta: dict, weights_sha256: str, backbone, num_samples: int, parser=None) -> dict:
    """What decides a trained baseline's placements: its run, weights, backbone, parser (if any), sample count."""
    described = {
        "method": name,
        "run": run_meta,
        "weights_sha256": weights_sha256,
        "backbone_fingerprint": backbone.fingerprint,
    }
    if parser is not None:
        described["parser"] = parser.name
    return {**described, "num_samples": num_samples}


# ----------------------------------------------------------------------------- Raw Image Grids


@dataclasses.dataclass
class GridsMethod:
    """Chooses the cell most similar to all tuple texts and samples a collision-free point inside it."""

    backbone: object
    parser: object
    params: dict
    config: grids.GridConfig
    run_meta: dict
    weights_sha256: str
    num_samples: int
    cells_cache: Path | None = None  # encoded cells per image, by content: evaluations of several runs share them
    name: str = "grids"

    def describe(self) -> dict:
        return _describe(self.name, self.run_meta, self.weights_sha256, self.backbone, self.num_samples, self.parser)

    def run(self, scenes: Sequence[SceneRecord], key) -> list[MethodOutput]:
        return [self._place(scene, scene_key) for scene, scene_key in zip(scenes, jax.random.split(key, len(scenes)))]

    def chosen_cell(self, scene: SceneRecord, parsed: Sequence[tuple[str, str]]) -> tuple[int, np.ndarray]:
        """`(cell, logits (num_cells,))` for one scene and its parse."""
        cells = self.encoded_cells(scene)
        text = self.backbone.encode_texts([grids.tuple_text(reference, relation) for reference, relation in parsed])
        logits = np.asarray(
            grids.jit_grid_logits(
                self.config, self.params, cells, text, np.ones(len(text), bool), float(self.run_meta["logit_scale"])
            )
        )
        return int(np.argmax(logits)), logits

    def encoded_cells(self, scene: SceneRecord) -> np.ndarray:
        """`(num_cells, D)` backbone features of the scene's cells, read from `cells_cache` when there."""

        def encode():
            crops = grids.cell_crops(scene.rgb, top_down_camera(scene), self.config)
            return np.asarray(self.backbone.encode_images(crops))

        if self.cells_cache is None:
            return encode()
        # The raw camera JSON, so that cells cached before stay found.
        image_key = scene.rgb.tobytes() + json.dumps(scene.meta["camera"], sort_keys=True).encode()
        path = self.cells_cache / f"{hashlib.sha256(image_key).hexdigest()[:32]}.npy"
        try:
            return np.load(path)
        except (OSError, ValueError):  # not cached yet, or a damaged file: encode (again)
            cells = encode()
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(path) as tmp, open(tmp, "wb") as file:
            np.save(file, cells)
        return cells

    def _place(self, scene: SceneRecord, key) -> MethodOutput:
        try:
            tuples = self.parser.parse(scene.instruction)
            parsed = tuple(as_pairs(tuples))
            cell, _ = self.chosen_cell(scene, parsed)
            samples, mode, _ = grids.sample_in_cell(key, free_grid(scene), cell, self.num_samples, self.config)
        except OcplaceError as error:
            return _failure(error)
        return MethodOutput(mode=mode, samples=samples, parsed=parsed, grounded=None, parse_note=parse_note(tuples))


def train_grids(context: TrainContext):
    from ocplace.train.grids import train_grids

    return _train(train_grids, context)


def load_grids(context: LoadContext) -> GridsMethod:
    from ocplace.models.parsing import make_parser

    params, run_meta, sha = grids.load_params(context.run_dir)
    config = grids.GridConfig.from_json(json.dumps(run_meta["grid"]))
    backbone = _load_backbone(context.backbone, run_meta, "Raw Image Grids")
    grid_key = hashlib.sha256(config.to_json().encode()).hexdigest()[:12]
    cells_cache = baselines_cache() / f"test-cells-{backbone.fingerprint[:16]}-{grid_key}"
    return GridsMethod(
        backbone, make_parser(context.parser), params, config, run_meta, sha, context.num_samples, cells_cache
    )


# ----------------------------------------------------------------------------- CLIPort-Place


@dataclasses.dataclass
class CliportMethod:
    """The argmax pixel of the affordance map as the mode; samples drawn from the map."""

    backbone: object
    params: dict
    config: cliport.CliportConfig
    run_meta: dict
    weights_sha256: str
    num_samples: int
    name: str = "cliport"

    def describe(self) -> dict:
        return _describe(self.name, self.run_meta, self.weights_sha256, self.backbone, self.num_samples)

    def distributions(self, scenes: Sequence[SceneRecord]) -> np.ndarray:
        """`(num_scenes, h * w)` pixel distributions (each sums to 1 over the table's pixels)."""
        out = []
        for start in range(0, len(scenes), SCENES_PER_BATCH):
            batch = list(scenes[start : start + SCENES_PER_BATCH])
            cameras = [top_down_camera(scene) for scene in batch]
            images = [cliport.prepare_image(s.rgb, s.depth, c, self.config) for s, c in zip(batch, cameras)]
            text = self.backbone.encode_texts([scene.instruction for scene in batch])
            pad = SCENES_PER_BATCH - len(batch)
            rgb = np.stack([i[0] for i in images] + [np.zeros_like(images[0][0])] * pad)
            height = np.stack([i[1] for i in images] + [np.zeros_like(images[0][1])] * pad)
            text = np.concatenate([text, np.zeros((pad, text.shape[1]), text.dtype)])
            mask = np.stack([cliport.table_mask(camera, self.config) for camera in cameras + cameras[:1] * pad])
            probabilities = cliport.jit_distribution(self.config, self.params, rgb, height, text, mask)
            out.append(np.asarray(probabilities)[: len(batch)])
        return np.concatenate(out) if out else np.zeros((0, self.config.num_pixels), np.float32)

    def run(self, scenes: Sequence[SceneRecord], key) -> list[MethodOutput]:
        try:
            distributions = self.distributions(scenes)
        except OcplaceError as error:
            return [_failure(error) for _ in scenes]
        outputs = []
        for scene, probabilities, scene_key in zip(scenes, distributions, jax.random.split(key, len(scenes))):
            mode, samples = cliport.mode_and_samples(
                scene_key, probabilities, self.num_samples, top_down_camera(scene), self.config
            )
            outputs.append(MethodOutput(mode=mode, samples=samples, parsed=None, grounded=None))
        return outputs


def train_cliport(context: TrainContext):
    from ocplace.train.cliport import train_cliport

    return _train(train_cliport, context)


def _train(train, context: TrainContext):
    """Both baselines train from the same context fields."""
    return train(
        context.dataset_dir,
        context.backbone,
        context.out_dir,
        context.recipe,
        context.fraction,
        context.seed,
        experiment=context.experiment,
    )


def load_cliport(context: LoadContext) -> CliportMethod:
    params, run_meta, sha = cliport.load_params(context.run_dir)
    config = cliport.CliportConfig.from_json(json.dumps(run_meta["network"]))
    return CliportMethod(
        _load_backbone(context.backbone, run_meta, "CLIPort-Place"), params, config, run_meta, sha, context.num_samples
    )


METHODS = (
    MethodSpec("grids", "Raw Image Grids", load=load_grids, train=train_grids),
    MethodSpec("cliport", "CLIPort-Place", load=load_cliport, train=train_cliport),
)
