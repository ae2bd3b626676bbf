"""`ocplace densities`: the paper's Fig. 5 (placement densities) on a real scene."""

from __future__ import annotations

import argparse
from pathlib import Path

from ocplace.cli.options import MAX_SEED, count
from ocplace.vocabulary import LIBRARY_SPLITS


def register(subparsers: argparse._SubParsersAction) -> None:
    densities = subparsers.add_parser(
        "densities",
        help="draw placement densities and samples on a real scene (paper Fig. 5)",
        description="Drops objects on the table (MuJoCo), then draws three placement densities over "
        "the top-down image: a table region, one object relation and a two-relation "
        "composition, with 1024 samples each (300 drawn) and the mode.",
    )
    densities.add_argument("--seed", type=count(0, MAX_SEED), default=0, help="scene seed; also picks the relations")
    densities.add_argument(
        "--split", choices=LIBRARY_SPLITS, default="seen", help="object and table-texture split to draw from"
    )
    densities.add_argument("--out", type=Path, default=Path("densities.png"), help="PNG to write")
    densities.set_defaults(func=_draw_densities)


def _draw_densities(args: argparse.Namespace) -> int:
    import jax
    import numpy as np

    from ocplace.models.placement.figures import fig5, save_figure
    from ocplace.sim.library import load_library
    from ocplace.sim.mujoco_backend import MujocoScenes
    from ocplace.sim.scene import render_sampled_scene

    library = load_library()
    with MujocoScenes.from_library(library) as arena:
        scene = render_sampled_scene(library, arena, args.seed, args.split)
        camera = arena.config.camera
    boxes = np.array([obj.aabb[:, :2] for obj in scene.objects])
    names = [library.get(obj.name).human_name for obj in scene.objects]
    held = library.get(scene.spec.held_object)
    half_extents = np.asarray(held.extents[:2], dtype=float) / 2.0
    figure = fig5(
        jax.random.key(args.seed),
        scene.rgb,
        camera,
        boxes,
        half_extents,
        rng=np.random.default_rng(args.seed),
        names=names,
        suptitle=f"seed {args.seed} | held: {held.human_name}",
        scene=f"seed {args.seed}",
    )
    save_figure(figure, args.out)
    print(f"wrote {args.out}")
    return 0
