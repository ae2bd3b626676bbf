"""`InstructionEmbedding`: the benchmark's Gymnasium environment with the instruction as a vector, for RL libraries.

Stable-Baselines3 (and most RL code) takes only Box, Discrete, MultiBinary and Dict observations; the
environment's `instruction` is a Text space. This wrapper replaces it with the instruction's all-MiniLM-L6-v2
sentence embedding (the offline backbone's frozen text tower: mean-pooled, unit length, 384 floats), so that
`stable_baselines3.common.env_checker.check_env` passes on the wrapped environment.
"""

from __future__ import annotations

import gymnasium
import numpy as np
from gymnasium import spaces

INSTRUCTION_TOKENS = 64  # MiniLM tokens read per instruction: the benchmark's stay under 40


class InstructionEmbedding(gymnasium.ObservationWrapper):
    """`observation["instruction"]`: `(384,)` float32 in [-1, 1] instead of the text; `encode` (texts -> `(L, D)`
    unit rows) defaults to the installed MiniLM."""

    def __init__(self, env: gymnasium.Env, encode=None):
        super().__init__(env)
        if encode is None:
            from ocplace.models.offline_backbone import FrozenTextTower

            encode = FrozenTextTower.load(INSTRUCTION_TOKENS).encode
        self._encode = encode
        dim = int(np.asarray(encode(["put it left of the mug."])).shape[-1])
        assert isinstance(env.observation_space, spaces.Dict), "the placement environment's observation is a Dict"
        observation_space = dict(env.observation_space.spaces)
        observation_space["instruction"] = spaces.Box(-1.0, 1.0, (dim,), np.float32)
        self.observation_space = spaces.Dict(observation_space)

    def observation(self, observation: dict) -> dict:
        embedding = np.clip(np.asarray(self._encode([observation["instruction"]])[0], np.float32), -1.0, 1.0)
        return observation | {"instruction": embedding}
