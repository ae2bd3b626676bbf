"""The vector environment: `gymnasium.make_vec("ocplace/Place-v0", num_envs=2, ...)` (its vector entry point).

Worker `i` of `n` plays episodes `i, i + n, i + 2n, ...` and, after `reset(seed=s)` (Gymnasium
seeds worker `i` with `s + i`), episodes `s + i, s + i + n, ...`: together the workers play the
single environment's episodes, the same scenes in the same order, `n` at a time. Each step ends
every worker's episode, so sub-environments reset in the same step (`AutoresetMode.SAME_STEP`): the
step returns the next scenes' observations, and the finished episodes' in `info["final_obs"]` and
`info["final_info"]`.
"""

from __future__ import annotations

import functools

from gymnasium.vector import AsyncVectorEnv, AutoresetMode

from ocplace.errors import PlaceEnvError


class PlaceVectorEnv(AsyncVectorEnv):
    """Gymnasium's `AsyncVectorEnv` that checks the whole batch of actions before it sends a row: a bad batch is
    an `InvalidAction` with nothing sent, so no worker is left holding a result the next step would return."""

    def step_async(self, actions) -> None:
        from ocplace.sim.env.place_env import action_rows

        what = f"a vector environment of {self.num_envs} takes one placement (x, y) per sub-environment"
        super().step_async(action_rows(actions, (self.num_envs, 2), what))


def make_vector_env(num_envs: int = 2, max_episode_steps: int | None = None, **kwargs) -> AsyncVectorEnv:
    """`num_envs` worker processes, each a `PlaceEnv(**kwargs, worker=i, workers=num_envs)`.

    Workers start by spawning, not forking: a fork after JAX or an OpenGL context started in this
    process is unsafe, and a policy in the same process usually runs JAX. `max_episode_steps`, which
    `gymnasium.make_vec` passes on, is accepted and changes nothing: every episode ends at its first step.
    """
    from ocplace.sim.env.place_env import PlaceEnv

    if num_envs < 1:
        raise PlaceEnvError(f"num_envs must be at least 1, got {num_envs}")
    if max_episode_steps is not None and max_episode_steps < 1:
        raise PlaceEnvError(f"max_episode_steps must be at least 1 (an episode is one step), got {max_episode_steps}")
    return PlaceVectorEnv(
        [functools.partial(PlaceEnv, **kwargs, worker=worker, workers=num_envs) for worker in range(num_envs)],
        context="spawn",
        # Gymnasium 1.4 reads a Text space out of shared memory once, when the vector env is made: every
        # instruction would come back as that first read ("aaa..."). Through the pipes they come back right.
        shared_memory=False,
        autoreset_mode=AutoresetMode.SAME_STEP,
    )
