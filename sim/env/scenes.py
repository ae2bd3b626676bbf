"""Where the placement environment's scenes come from: a dataset split, or the generator on the fly.

Both are sequences of `SceneRecord`s in a fixed order: a dataset's listing order (scene-id order,
what the evaluation harness runs), or the generator's indices of a split. A generated scene is the
scene `ocplace generate` writes with the same configuration, as reading it back gives it (without
encoding its PNGs), so an environment over either source shows the same observation bytes.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from ocplace.sim.dataset.config import DatasetConfig
from ocplace.sim.dataset.records import SceneRecord, stored_record
from ocplace.sim.pinhole import PinholeCamera

if TYPE_CHECKING:
    from ocplace.sim.dataset.generate import SceneGenerator


class DatasetScenes:
    """The scenes of `split` that the dataset's manifest lists, each file checked against its sha256 as read."""

    def __init__(self, dataset_dir: str | Path, split: str):
        from ocplace.sim.dataset.job import listed_scenes

        self._listed = listed_scenes(dataset_dir, split)

    def __len__(self) -> int:
        return len(self._listed)

    def camera(self) -> PinholeCamera:
        """The camera of the first scene: a dataset renders every scene with one camera."""
        return self._listed[0].info().camera

    def record(self, index: int) -> SceneRecord:
        return self._listed[index].read()

    def close(self) -> None:
        """Nothing to release: scenes are read file by file."""


class GeneratedScenes:
    """The scenes of `split` in the dataset `config` describes, made when asked for (about 0.1 s each).

    The library is loaded and the MuJoCo arena compiled on the first scene, not on construction, so
    building one only to read its spaces (as Gymnasium's vector environments do) costs nothing.
    """

    def __init__(self, config: DatasetConfig, split: str, library_cache: str | Path | None = None):
        from ocplace.sim.dataset.generate import level_schedule

        config.validate()
        self._config, self._split, self._cache = config, split, library_cache
        self._levels = level_schedule(config.split(split), config.seed)
        self._generator: SceneGenerator | None = None

    def __len__(self) -> int:
        return len(self._levels)

    def camera(self) -> PinholeCamera:
        from ocplace.sim.mujoco_backend import default_config

        return PinholeCamera.from_any(default_config().camera)  # the arena `SceneGenerator` builds renders with it

    def record(self, index: int) -> SceneRecord:
        if self._generator is None:
            from ocplace.sim.dataset.generate import SceneGenerator
            from ocplace.sim.library import load_library

            self._generator = SceneGenerator(load_library(self._cache), self._config)
        meta, scene = self._generator.make_scene(self._split, index, self._levels[index])
        return stored_record(meta, scene.rgb, scene.depth, scene.segmentation)

    def close(self) -> None:
        if self._generator is not None:
            self._generator.close()
            self._generator = None
