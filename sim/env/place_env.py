"""The benchmark as a Gymnasium environment: one episode is one scene, one step is one placement.

`reset` shows the scene (`observation.py`); `step((x, y))` scores the placement with the benchmark's
success metric (`sim.metric`, as the evaluation harness scores a method's mode), optionally drops the
held object in MuJoCo (`sim.physical`), and ends the episode. Which scene an episode plays is a
function of the seed: `reset(seed=k)` plays scene `k mod N` of the source's order; an unseeded reset
plays the next one, `workers` further on (the vector environment's workers interleave,
`vector.py`). docs/evaluation.md#the-gymnasium-environment has the spaces and the decisions.
"""

from __future__ import annotations

import copy
import dataclasses
import os
import sys
import types
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2
import gymnasium
import numpy as np
from gymnasium import spaces

from ocplace.errors import InvalidAction, PlaceEnvError
from ocplace.sim.dataset.config import DatasetConfig, make_config
from ocplace.sim.dataset.records import SceneRecord
from ocplace.sim.env.observation import observation, observation_space
from ocplace.sim.env.scenes import DatasetScenes, GeneratedScenes
from ocplace.sim.metric import check_placements
from ocplace.sim.workspace import DEFAULT_TABLE

if TYPE_CHECKING:
    from ocplace.sim.mujoco_backend import MujocoScenes

SUCCESS_COLOUR = (40, 200, 60)  # RGB of a successful placement's footprint in `render()`
FAILURE_COLOUR = (230, 40, 40)
# Where Gymnasium's `make_vec` lives: its sync/async copies are refused (`_made_by_gymnasiums_vectorizer`).
VECTORIZER_FILE = os.path.join("gymnasium", "envs", "registration.py")
PIXEL_LIMIT = 1 << 15  # OpenCV draws with shifted fixed-point coordinates: larger ones overflow


def _made_by_gymnasiums_vectorizer() -> bool:
    """Whether Gymnasium's own sync/async vectorizer is making this environment: its `make_vec` builds each copy in
    a closure named `create_single_env`, with nothing in the arguments that tells the copies apart (Gymnasium
    offers no other hook), so that closure on the call stack is the only sign."""
    frame: types.FrameType | None = sys._getframe(1)
    for _ in range(32):
        if frame is None:
            return False
        code = frame.f_code
        if code.co_name == "create_single_env" and code.co_filename.endswith(VECTORIZER_FILE):
            return True
        frame = frame.f_back
    return False


def action_rows(action, shape: tuple[int, ...], what: str) -> np.ndarray:
    """float64 `action` of `shape`; InvalidAction (saying `what` an action is) unless it is numbers of that shape.
    The one check of the single and the vector environment: strings, booleans and objects are refused, although
    "0.1" and True would convert."""
    try:
        if np.asarray(action).dtype.kind not in "iuf":
            raise TypeError(f"not numbers but {np.asarray(action).dtype}")
        rows = np.asarray(action, dtype=np.float64)
    except Exception as error:  # TypeError, ValueError, OverflowError (10**400), or whatever an __array__ raises
        raise InvalidAction(f"{what}, numbers of shape {shape}; got {type(action).__name__} ({error})") from None
    if rows.shape != shape:
        raise InvalidAction(f"{what}, shape {shape}; got shape {rows.shape}")
    return rows


def placement_of(action) -> np.ndarray:
    """`(2,)` float64 table-frame `(x, y)` of an action; InvalidAction when it is not two numbers."""
    what = (
        "an action is a placement (x, y) in metres in the table frame (a vector environment takes one row per "
        "sub-environment, shape (num_envs, 2))"
    )
    return action_rows(action, (2,), what)


def metric_details(record: SceneRecord, placement: np.ndarray) -> dict:
    """Whether `placement` succeeds on `record`'s ground truth, each part of the metric, and why not."""
    if not np.all(np.isfinite(placement)):
        reason = "the placement is not finite (NaN or infinite)"
        return {"success": False, "reason": reason, "inside_table": None, "collision_free": None, "tuples_hold": None}
    checks = check_placements(placement[None], record.problem())
    tuples_hold = [bool(holds) for holds in checks.tuples[: len(record.true_tuples()), 0]]
    reasons = [
        f"{truth.relation} {truth.reference_name} does not hold"
        for truth, holds in zip(record.true_tuples(), tuples_hold)
        if not holds
    ]
    if not checks.inside_table[0]:
        reasons.append("the held object's footprint leaves the table")
    if not checks.collision_free[0]:
        reasons.append("the held object's footprint overlaps a scene object")
    return {
        "success": bool(checks.success[0]),
        "reason": "; ".join(reasons) or None,
        "inside_table": bool(checks.inside_table[0]),
        "collision_free": bool(checks.collision_free[0]),
        "tuples_hold": tuples_hold,
    }


def ground_truth(record: SceneRecord) -> dict:
    """What `info` reveals once the episode is over: the level, the tuples (with token indices), the oracle."""
    return {
        "level": record.level,
        "tuples": [dataclasses.asdict(t) for t in record.true_tuples()],
        "oracle": record.true_placement().tolist(),
    }


class PlaceEnv(gymnasium.Env):
    """Place the held object where the instruction says. Reward 1 for a successful placement, else 0.

    Args:
      dataset: a dataset folder (`ocplace generate`); None: scenes are generated on the fly.
      split: the split whose scenes the episodes play ("seen", "unseen_obj", ...).
      generator: without `dataset`, the dataset configuration to generate from (default
        `make_config()`: the paper's layout, seed 0); the same configuration gives the same scene bytes
        as `ocplace generate`.
      physical_check: also drop the held object in MuJoCo; the reward is then 1 only when the metric
        and the drop both succeed (the harness's physical success).
      render_mode: None or "rgb_array".
      worker, workers: this environment plays episodes `worker, worker + workers, ...` until seeded;
        the vector environment sets them so that its workers share out the single environment's episodes.
      library_cache: the cache holding the object library (default `~/.cache/ocplace`), for generating
        scenes and for the physical check.
    """

    metadata: dict[str, Any] = {"render_modes": ["rgb_array"], "render_fps": 4}  # noqa: RUF012 (Env declares it so)

    def __init__(
        self,
        dataset: str | Path | None = None,
        split: str = "seen",
        *,
        generator: DatasetConfig | None = None,
        physical_check: bool = False,
        render_mode: str | None = None,
        worker: int = 0,
        workers: int = 1,
        library_cache: str | Path | None = None,
    ):
        if workers == 1 and _made_by_gymnasiums_vectorizer():
            raise PlaceEnvError(
                "gymnasium.make_vec(..., vectorization_mode='sync' or 'async') makes every copy of this environment "
                "with the same arguments, so each would play the same scenes; use the default mode "
                "(vectorization_mode=None), whose workers split the scenes without overlap (docs/evaluation.md)"
            )
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise PlaceEnvError(f"render_mode is None or 'rgb_array', got {render_mode!r}")
        if not 0 <= worker < workers:
            raise PlaceEnvError(f"worker must lie in [0, workers), got worker={worker}, workers={workers}")
        if dataset is not None and generator is not None:
            raise PlaceEnvError("give a dataset folder or a generator configuration, not both")
        self.scenes = (
            DatasetScenes(dataset, split)
            if dataset is not None
            else GeneratedScenes(generator or make_config(), split, library_cache)
        )
        self.physical_check = physical_check
        self.render_mode = render_mode
        self.observation_space = observation_space(self.scenes.camera())
        bounds = DEFAULT_TABLE.bounds.astype(np.float32)
        self.action_space = spaces.Box(bounds[0], bounds[1], dtype=np.float32)
        self._workers, self._next_episode = workers, worker
        self._library_cache = library_cache
        self._arena: MujocoScenes | None = None  # MuJoCo arena of the physical check, made on its first drop
        self._record: SceneRecord | None = None
        self._observation: dict | None = None
        self._placement: np.ndarray | None = None
        self._reward = 0.0

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Shows scene `seed mod N` (seeded) or the next scene of this worker's episodes (unseeded)."""
        super().reset(seed=seed)
        episode = self._next_episode if seed is None else int(seed)
        self._next_episode = episode + self._workers
        index = episode % len(self.scenes)
        self._record = self.scenes.record(index)
        self._observation = observation(self._record)
        self._placement = None
        return self._observation, {"scene": self._record.id, "index": index, "episode_index": episode}

    def step(self, action):
        """Scores the placement `(x, y)`; the episode ends. Non-finite or off-table actions score 0 with a reason."""
        if self._record is None:
            raise PlaceEnvError("call reset() before step(): an episode shows a scene first")
        if self._placement is not None:
            raise PlaceEnvError("this episode already ended with a placement; call reset() for the next scene")
        placement = placement_of(action)
        details = metric_details(self._record, placement)
        physical = self._physical(placement, details["success"]) if self.physical_check else None
        success = details["success"] and (physical is None or physical["success"])
        self._placement, self._reward = placement, float(success)
        info = details | {
            "placement": placement.tolist(),
            "physical": physical,
            "scene": self._record.id,
            "truth": ground_truth(self._record),
        }
        # A copy: Gymnasium users keep what `reset` returned, so `step` must not hand out the same arrays.
        return copy.deepcopy(self._observation), self._reward, True, False, info

    def _physical(self, placement: np.ndarray, metric_success: bool) -> dict:
        """The drop check as the harness reports it; nothing is dropped where the metric already failed."""
        if not metric_success:
            return {"success": False, "dropped": False, "held_offset": None, "max_disturbance": None}
        from ocplace.sim.physical import physical_check

        if self._arena is None:
            from ocplace.sim.library import load_library
            from ocplace.sim.mujoco_backend import MujocoScenes

            self._arena = MujocoScenes.from_library(load_library(self._library_cache))
        assert self._record is not None, "stepped after a reset"
        result = physical_check(self._arena, self._record, placement)
        return {
            "success": bool(result.success),
            "dropped": True,
            "held_offset": float(result.held_offset),
            "max_disturbance": float(result.max_disturbance),
        }

    def render(self):
        """`(H, W, 3)` uint8: the scene, with the held object's footprint at the placement once stepped
        (green: reward 1, red: 0). None unless render_mode is "rgb_array"."""
        if self.render_mode is None:
            return None
        if self._record is None:
            raise PlaceEnvError("call reset() before render(): there is no scene to draw yet")
        frame = self._record.rgb.copy()
        if self._placement is None or not np.all(np.isfinite(self._placement)):
            return frame
        half = self._record.held_object.footprint_half_extents
        corners = self._placement + half * np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]])
        pixels = self._pixels(corners)
        centre = self._pixels(self._placement)
        colour = SUCCESS_COLOUR if self._reward else FAILURE_COLOUR
        cv2.polylines(frame, [pixels], isClosed=True, color=colour, thickness=2)
        cv2.drawMarker(frame, (int(centre[0]), int(centre[1])), colour, cv2.MARKER_CROSS, 12, 2)
        return frame

    def _pixels(self, xy: np.ndarray) -> np.ndarray:
        """`(..., 2)` int32 pixels of table points, clipped so that a placement far off the table still draws."""
        assert self._record is not None, "drawn after a reset"
        pixels = self._record.camera.table_to_pixel(xy)
        return np.clip(np.round(pixels), -PIXEL_LIMIT, PIXEL_LIMIT).astype(np.int32)

    def close(self):
        self.scenes.close()
        if self._arena is not None:
            self._arena.close()
            self._arena = None
