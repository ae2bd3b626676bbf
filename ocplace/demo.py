"""`ocplace demo`: the main job, end to end at a small scale."""

from __future__ import annotations

import argparse
from pathlib import Path


def register(subparsers: argparse._SubParsersAction) -> None:
    demo = subparsers.add_parser(
        "demo",
        help="build the object library and show what ocplace does, in out/demo/",
        description="Builds (or reuses) the object library cache, then drops objects on the table in "
        "MuJoCo and saves labelled pictures of a seen and an unseen scene.",
    )
    demo.add_argument("--out", type=Path, default=Path("out/demo"), help="folder for the pictures")
    demo.add_argument("--seed", type=int, default=0)
    demo.set_defaults(func=run_demo)


def run_demo(args: argparse.Namespace) -> int:
    from ocplace.sim.commands import render_sampled_scene
    from ocplace.sim.figures import labelled_scene, save_png
    from ocplace.sim.library import build_library, default_config
    from ocplace.sim.mujoco_backend import MujocoScenes
    from ocplace.sim.splits import LIBRARY_SPLITS

    library = build_library(default_config())
    print(f"object library: {library.summary()}")
    with MujocoScenes.from_library(library) as arena:
        for split in LIBRARY_SPLITS:
            scene = render_sampled_scene(library, arena, args.seed, split)
            held = library.get(scene.spec.held_object).human_name
            title = f"{split} objects and table | held object: {held}"
            path = save_png(args.out / f"scene_{split}.png", labelled_scene(scene, library, title))
            names = ", ".join(library.get(obj.name).human_name for obj in scene.objects)
            print(f"{split:>10} scene: {names} -> {path}")
    return 0
