"""The benchmark as a Gymnasium environment, registered as `ocplace/Place-v0` when this module is imported.

Gymnasium 1.x loads no plugins (its `gymnasium.envs` entry points went in 1.0), so
`gymnasium.make("ocplace.sim.env:ocplace/Place-v0", dataset=DIR, split="seen")` names this module
before the id: Gymnasium imports it, and so registers the environment, on the way. Registering needs
nothing but Gymnasium: the environment's own modules load when one is made.
"""

from gymnasium.envs.registration import register

ENV_ID = "ocplace/Place-v0"
MAKE_ID = f"{__name__}:{ENV_ID}"  # the id that registers the environment on the way: no import needed

register(
    id=ENV_ID,
    entry_point="ocplace.sim.env.place_env:PlaceEnv",
    vector_entry_point="ocplace.sim.env.vector:make_vector_env",
)
