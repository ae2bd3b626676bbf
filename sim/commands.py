"""CLI commands for scenes: `ocplace scene` and `ocplace parity`."""

from __future__ import annotations

import argparse
from pathlib import Path


def register(subparsers: argparse._SubParsersAction) -> None:
    scene = subparsers.add_parser(
        "scene", help="drop objects on the table, render them and save a labelled picture",
        description="Samples a scene from the object library, settles it in MuJoCo and saves "
                    "RGB with labelled boxes, depth and segmentation side by side.")
    scene.add_argument("--seed", type=int, default=0, help="scene seed (same seed, same picture)")
    scene.add_argument("--split", choices=("seen", "unseen"), default="seen",
                       help="object and table-texture split to draw from")
    scene.add_argument("--out", type=Path, default=Path("scene.png"), help="PNG to write")
    scene.set_defaults(func=_scene)


def _scene(args: argparse.Namespace) -> int:
    import numpy as np

    from ocplace.sim.boxes import boxes_from_segmentation
    from ocplace.sim.figures import save_png, scene_panel
    from ocplace.sim.library import load_library
    from ocplace.sim.mujoco_backend import MujocoScenes
    from ocplace.sim.scene import sample_scene_spec, split_pools

    library = load_library()
    objects, textures = split_pools(library, args.split)
    spec = sample_scene_spec(np.random.default_rng(args.seed), objects, textures)
    with MujocoScenes.from_library(library) as arena:
        scene = arena.build(spec)
    boxes = boxes_from_segmentation(scene.segmentation)
    labels = {obj.object_id: library.get(obj.name).human_name for obj in scene.objects}
    title = f"seed {args.seed} | {args.split} | table: {spec.table_texture} | held: {library.get(spec.held_object).human_name}"
    save_png(args.out, scene_panel(scene.rgb, scene.depth, scene.segmentation, boxes, labels, title))
    print(f"wrote {args.out}: {len(boxes)} boxes for {len(scene.objects)} objects")
    return 0
