"""`ocplace scene` and `ocplace parity`: one rendered scene, and MuJoCo against PyBullet."""

from __future__ import annotations

import argparse
from pathlib import Path

from ocplace.cli.options import MAX_SCENES, MAX_SEED, count
from ocplace.vocabulary import LIBRARY_SPLITS


def register(subparsers: argparse._SubParsersAction) -> None:
    scene = subparsers.add_parser(
        "scene",
        help="drop objects on the table, render them and save a labelled picture",
        description="Samples a scene from the object library, settles it in MuJoCo and saves "
        "RGB with labelled boxes, depth and segmentation side by side.",
    )
    scene.add_argument("--seed", type=count(0, MAX_SEED), default=0, help="scene seed (same seed, same picture)")
    scene.add_argument(
        "--split", choices=LIBRARY_SPLITS, default="seen", help="object and table-texture split to draw from"
    )
    scene.add_argument("--out", type=Path, default=Path("scene.png"), help="PNG to write")
    scene.set_defaults(func=_scene)

    parity = subparsers.add_parser(
        "parity",
        help="compare MuJoCo and PyBullet renders and drops on the same scenes",
        description="(a) physics off: projected object centres and segmentation boxes; (b) depth on "
        "table pixels; (c) both engines settle every dropped object on the table.",
    )
    parity.add_argument("--scenes", type=count(1, MAX_SCENES), default=50, help="number of scenes to compare")
    parity.add_argument("--seed", type=count(0, MAX_SEED), default=0, help="seed of the first scene (default 0)")
    parity.add_argument("--renderer", choices=("tiny", "egl"), default="tiny", help="PyBullet renderer")
    parity.add_argument("--out", type=Path, help="also write the full report as JSON here")
    parity.set_defaults(func=_parity)


def _scene(args: argparse.Namespace) -> int:
    from ocplace.sim.figures import labelled_scene, save_png
    from ocplace.sim.library import load_library
    from ocplace.sim.mujoco_backend import MujocoScenes
    from ocplace.sim.scene import render_sampled_scene

    library = load_library()
    with MujocoScenes.from_library(library) as arena:
        scene = render_sampled_scene(library, arena, args.seed, args.split)
    held = library.get(scene.spec.held_object).human_name
    title = f"seed {args.seed} | {args.split} | table: {scene.spec.table_texture} | held: {held}"
    save_png(args.out, labelled_scene(scene, library, title))
    print(f"wrote {args.out}: {len(scene.objects)} objects, settled in {scene.settle_steps} steps")
    return 0


def _parity(args: argparse.Namespace) -> int:
    import json

    from ocplace.errors import OcplaceError
    from ocplace.paths import write_text_atomic
    from ocplace.sim.library import load_library
    from ocplace.sim.parity import ParityConfig, run_parity

    if args.scenes < 1:
        raise OcplaceError("--scenes must be at least 1")
    config = ParityConfig(scenes=args.scenes, seed=args.seed, renderer=args.renderer)
    report = run_parity(load_library(), config)
    summary = report["summary"]
    print(f"scenes compared:                     {summary['scenes']}")
    centre_error = summary["max_centre_error_px"]
    print(f"(a) max projected centre error:      {centre_error:.3f} px (<= {config.centre_tolerance_px})")
    dv, du = summary["mean_mask_centroid_offset_px"]
    print(f"(a) mean mask centroid offset:       {dv:+.3f} rows, {du:+.3f} columns")
    iou = summary["min_box_iou"]
    print(f"(a) min box IoU (>= {config.iou_min_pixels} px objects): {iou:.3f} (>= {config.iou_threshold})")
    print(
        f"(b) max table depth error:           {summary['max_table_depth_error_m'] * 1000:.2f} mm "
        f"(<= {config.depth_tolerance_m * 1000:.1f})"
    )
    print(
        f"(c) settled on the table: MuJoCo {summary['mujoco_settled_on_table']}/{summary['scenes']}, "
        f"PyBullet {summary['pybullet_settled_on_table']}/{summary['scenes']}"
    )
    print("PASS" if summary["passed"] else "FAIL")
    if args.out:
        write_text_atomic(args.out, json.dumps(report, indent=2))
    return 0 if summary["passed"] else 1
