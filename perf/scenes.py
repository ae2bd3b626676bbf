"""Scenes per second: sample, settle and render RGB + depth + segmentation at 640x480.

MuJoCo (one compiled arena, one renderer reused) against PyBullet's TinyRenderer path on the same
scene specs, in the same run. Usage: `python perf/scenes.py [--scenes 40]`.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import ocplace  # noqa: F401  (sets the headless OpenGL default before MuJoCo loads)
from ocplace.sim.library import load_library
from ocplace.sim.mujoco_backend import MujocoScenes, object_hull_points
from ocplace.sim.pybullet_backend import PybulletScenes
from ocplace.sim.scene import sample_scene_spec, split_pools


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=40)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    library = load_library()
    objects, textures = split_pools(library, "seen")
    rng = np.random.default_rng(args.seed)
    specs = [sample_scene_spec(rng, objects, textures) for _ in range(args.scenes)]

    start = time.perf_counter()
    arena = MujocoScenes.from_library(library)
    arena.build(specs[0])  # creates the GL context
    mujoco_setup = time.perf_counter() - start
    start = time.perf_counter()
    steps = [arena.build(spec).settle_steps for spec in specs]
    mujoco_seconds = time.perf_counter() - start
    arena.close()

    hulls = {name: object_hull_points(library.get(name)) for name in library.names()}
    start = time.perf_counter()
    pybullet = PybulletScenes(
        [library.get(n) for n in library.names()], {n: t.path for n, t in library.textures.items()}
    )
    pybullet.activate(library.names())  # loads every URDF once, like the MuJoCo arena compile
    pybullet.activate(())
    pybullet_setup = time.perf_counter() - start
    start = time.perf_counter()
    for spec in specs:
        pybullet.drop(spec, hulls)
        pybullet.render(spec.objects)
    pybullet_seconds = time.perf_counter() - start
    pybullet.close()

    mujoco_rate, pybullet_rate = args.scenes / mujoco_seconds, args.scenes / pybullet_seconds
    print(f"scenes: {args.scenes} (seen split, {len(library.names())} objects in the arena)")
    print(
        f"MuJoCo:   {mujoco_rate:6.2f} scenes/s  ({1000 / mujoco_rate:.1f} ms/scene, "
        f"{np.mean(steps):.0f} settle steps on average; set-up {mujoco_setup:.2f} s, not counted)"
    )
    print(
        f"PyBullet: {pybullet_rate:6.2f} scenes/s  ({1000 / pybullet_rate:.1f} ms/scene; "
        f"set-up {pybullet_setup:.2f} s, not counted)"
    )
    print(f"ratio MuJoCo / PyBullet: {mujoco_rate / pybullet_rate:.1f}x")


if __name__ == "__main__":
    main()
