"""Table I row "CLIPort-Place" (docs/baselines.md): an affordance map over the table's pixels from the
image and the instruction; its argmax pixel is the placement, samples are drawn from it."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import jax
import numpy as np

from ocplace import serial
from ocplace.errors import OcplaceError
from ocplace.eval.api import MethodOutput
from ocplace.methods.cliport import model as cliport
from ocplace.methods.cliport.recipe import CliportConfig
from ocplace.methods.cliport.recipe import CliportRecipe as Recipe
from ocplace.methods.contract import LoadContext, MethodSpec, TrainContext
from ocplace.methods.trained_baseline import TrainedRun, failure_output, train_baseline
from ocplace.models.baselines.common import top_down_camera
from ocplace.sim.dataset.records import SceneRecord

if TYPE_CHECKING:
    pass

SCENES_PER_BATCH = 8  # CLIPort scenes per network call (a fixed shape: one compilation)


@dataclasses.dataclass
class CliportMethod:
    """The argmax pixel of the affordance map as the mode; samples drawn from the map."""

    trained: TrainedRun
    config: CliportConfig
    name: str = "cliport"

    def describe(self) -> dict[str, Any]:
        return self.trained.describe(self.name)

    def distributions(self, scenes: Sequence[SceneRecord]) -> np.ndarray:
        """`(num_scenes, h * w)` pixel distributions (each sums to 1 over the table's pixels)."""
        out = []
        for start in range(0, len(scenes), SCENES_PER_BATCH):
            batch = list(scenes[start : start + SCENES_PER_BATCH])
            cameras = [top_down_camera(scene) for scene in batch]
            images = [cliport.prepare_image(s.rgb, s.depth, c, self.config) for s, c in zip(batch, cameras)]
            text = self.trained.backbone.encode_texts([scene.instruction for scene in batch])
            pad = SCENES_PER_BATCH - len(batch)
            rgb = np.stack([i[0] for i in images] + [np.zeros_like(images[0][0])] * pad)
            height = np.stack([i[1] for i in images] + [np.zeros_like(images[0][1])] * pad)
            text = np.concatenate([text, np.zeros((pad, text.shape[1]), text.dtype)])
            mask = np.stack([cliport.table_mask(camera, self.config) for camera in cameras + cameras[:1] * pad])
            probabilities = cliport.jit_distribution(self.config, self.trained.params, rgb, height, text, mask)
            out.append(np.asarray(probabilities)[: len(batch)])
        return np.concatenate(out) if out else np.zeros((0, self.config.num_pixels), np.float32)

    def run(self, scenes: Sequence[SceneRecord], key: jax.Array) -> list[MethodOutput]:
        try:
            distributions = self.distributions(scenes)
        except OcplaceError as error:
            return [failure_output(error) for _ in scenes]
        outputs = []
        for scene, probabilities, scene_key in zip(scenes, distributions, jax.random.split(key, len(scenes))):
            mode, samples = cliport.mode_and_samples(
                scene_key, probabilities, self.trained.num_samples, top_down_camera(scene), self.config
            )
            outputs.append(MethodOutput(mode=mode, samples=samples, parsed=None, grounded=None))
        return outputs


def train(context: TrainContext[Recipe]) -> Path:
    from ocplace.methods.cliport.train import train_cliport

    return train_baseline(train_cliport, context)


def load(context: LoadContext) -> CliportMethod:
    run = TrainedRun.load(context, cliport.load_params, "CLIPort-Place")
    return CliportMethod(run, serial.from_dict(CliportConfig, run.run_meta["network"]))


SPEC: MethodSpec[Recipe] = MethodSpec("cliport", "CLIPort-Place", load=load, train=train)
