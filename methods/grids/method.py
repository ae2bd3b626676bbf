"""Table I row "Raw Image Grids" (docs/baselines.md): the table cut into cells, the cell most similar to the
parsed tuples chosen, a collision-free point sampled inside it."""

from __future__ import annotations

import dataclasses
import hashlib
import json
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import jax
import numpy as np

from ocplace import serial
from ocplace.errors import OcplaceError
from ocplace.eval.api import MethodOutput
from ocplace.methods.contract import LoadContext, MethodSpec, TrainContext
from ocplace.methods.grids import model as grids
from ocplace.methods.grids.recipe import GridConfig
from ocplace.methods.grids.recipe import GridsRecipe as Recipe
from ocplace.methods.trained_baseline import TrainedRun, failure_output, train_baseline
from ocplace.models.baselines.common import free_grid, top_down_camera
from ocplace.models.parsing.types import as_pairs, parse_note
from ocplace.paths import atomic_path, baselines_cache
from ocplace.sim.dataset.records import SceneRecord

if TYPE_CHECKING:
    from ocplace.models.parsing.types import Parser


@dataclasses.dataclass
class GridsMethod:
    """Chooses the cell most similar to all tuple texts and samples a collision-free point inside it."""

    trained: TrainedRun
    parser: Parser
    config: GridConfig
    cells_cache: Path | None = None  # encoded cells per image, by content: evaluations of several runs share them
    name: str = "grids"

    def describe(self) -> dict[str, Any]:
        return self.trained.describe(self.name, self.parser)

    def run(self, scenes: Sequence[SceneRecord], key: jax.Array) -> list[MethodOutput]:
        return [self._place(scene, scene_key) for scene, scene_key in zip(scenes, jax.random.split(key, len(scenes)))]

    def chosen_cell(self, scene: SceneRecord, parsed: Sequence[tuple[str, str]]) -> tuple[int, np.ndarray]:
        """`(cell, logits (num_cells,))` for one scene and its parse."""
        cells = self.encoded_cells(scene)
        text = self.trained.backbone.encode_texts(
            [grids.tuple_text(reference, relation) for reference, relation in parsed]
        )
        logits = np.asarray(
            grids.jit_grid_logits(
                self.config,
                self.trained.params,
                cells,
                text,
                np.ones(len(text), bool),
                float(self.trained.run_meta["logit_scale"]),
            )
        )
        return int(np.argmax(logits)), logits

    def encoded_cells(self, scene: SceneRecord) -> np.ndarray:
        """`(num_cells, D)` backbone features of the scene's cells, read from `cells_cache` when there."""

        def encode() -> np.ndarray[Any, Any]:
            crops = grids.cell_crops(scene.rgb, top_down_camera(scene), self.config)
            return np.asarray(self.trained.backbone.encode_images(crops))

        if self.cells_cache is None:
            return encode()
        # The raw camera JSON, so that cells cached before stay found.
        image_key = scene.rgb.tobytes() + json.dumps(scene.meta["camera"], sort_keys=True).encode()
        path = self.cells_cache / f"{hashlib.sha256(image_key).hexdigest()[:32]}.npy"
        try:
            cached: np.ndarray[Any, Any] = np.load(path)
            return cached
        except (OSError, ValueError):  # not cached yet, or a damaged file: encode (again)
            cells = encode()
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(path) as tmp, open(tmp, "wb") as file:
            np.save(file, cells)
        return cells

    def _place(self, scene: SceneRecord, key: jax.Array) -> MethodOutput:
        try:
            tuples = self.parser.parse(scene.instruction)
            parsed = tuple(as_pairs(tuples))
            cell, _ = self.chosen_cell(scene, parsed)
            samples, mode, _ = grids.sample_in_cell(key, free_grid(scene), cell, self.trained.num_samples, self.config)
        except OcplaceError as error:
            return failure_output(error)
        return MethodOutput(mode=mode, samples=samples, parsed=parsed, grounded=None, parse_note=parse_note(tuples))


def train(context: TrainContext[Recipe]) -> Path:
    from ocplace.methods.grids.train import train_grids

    return train_baseline(train_grids, context)


def load(context: LoadContext) -> GridsMethod:
    from ocplace.models.parsing import make_parser

    run = TrainedRun.load(context, grids.load_params, "Raw Image Grids")
    config = serial.from_dict(GridConfig, run.run_meta["grid"])
    grid_key = hashlib.sha256(serial.to_json(config).encode()).hexdigest()[:12]
    cells_cache = baselines_cache() / f"test-cells-{run.backbone.fingerprint[:16]}-{grid_key}"
    return GridsMethod(run, make_parser(context.parser), config, cells_cache)


SPEC: MethodSpec[Recipe] = MethodSpec("grids", "Raw Image Grids", load=load, train=train)
