"""`ocplace place`: run the placement policy on a dataset scene or on your own RGB-D images."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path
from typing import Any

from ocplace.cli.options import MAX_SEED, count, number
from ocplace.vocabulary import DECISION_MODES, MAX_SAMPLES, MAX_TOP_K

HELD_FOOTPRINT = (0.05, 0.05)  # half-extents (m) of your own images' held object unless --held-footprint says
OWN_IMAGE_FLAGS = {
    "--rgb": "rgb",
    "--depth": "depth",
    "--segmentation": "segmentation",
    "--camera": "camera",
    "--held-footprint": "held_footprint",
}


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "place",
        help="place the held object in one scene with the policy and draw what it did",
        description="Parses the instruction, grounds each reference among the object boxes, samples placements "
        "and prints them (table frame and pixels). Input: a dataset scene (--dataset DIR --id K), or "
        "your own images (--rgb, --depth, --instruction; boxes from --segmentation or the depth "
        "detector). Writes a figure: image, boxes, grounded references, density, samples, mode.",
    )
    source = parser.add_argument_group("a dataset scene")
    source.add_argument("--dataset", type=Path, help="dataset directory (written by `ocplace generate`)")
    source.add_argument("--id", help="scene id (e.g. seen-00003) or its index within --split")
    source.add_argument("--split", default="seen", help="the split a numeric --id counts in (default: seen)")
    source.add_argument(
        "--detect",
        action="store_true",
        help="use the depth detector and depth-estimated AABBs instead of the dataset's boxes/AABBs",
    )
    own = parser.add_argument_group("your own images")
    own.add_argument("--rgb", type=Path, help="colour image (PNG/JPEG)")
    own.add_argument("--depth", type=Path, help="depth: uint16 PNG in millimetres, or .npy float metres")
    own.add_argument(
        "--segmentation",
        type=Path,
        help="optional segmentation PNG (0 = background); without it, boxes come from the depth detector",
    )
    own.add_argument(
        "--camera",
        type=Path,
        help="camera JSON: intrinsics (3x3), world_from_camera (4x4, table "
        "frame, metres), width, height; default: the simulator's camera",
    )
    own.add_argument(
        "--held-footprint",
        type=number(0.001, 1.0),
        nargs=2,
        metavar=("HX", "HY"),
        help="half-extents of the held object's footprint in metres (default 0.05 0.05)",
    )
    parser.add_argument("--instruction", help="the instruction (a dataset scene's own by default)")
    model = parser.add_argument_group("model")
    model.add_argument(
        "--backbone",
        help="backbone spec (default: the saved offline backbone the --adapters were trained with, found by its "
        "fingerprint, else the spec their training recorded; without --adapters: offline); with --policy, where a "
        "CLIP policy folder's checkpoint is now (clip:DIR), checked by its fingerprint",
    )
    model.add_argument(
        "--adapters", type=Path, help="training run directory or adapters file (default: none, zero-shot grounding)"
    )
    model.add_argument(
        "--policy",
        type=Path,
        help="a policy folder (`ocplace export`; out/demo/policy after `make demo`): backbone, adapters and "
        "settings in one, no cache needed; not with --backbone or --adapters",
    )
    model.add_argument("--parser", help="offline, offline-snap or llm (default: a --policy folder's, else offline)")
    model.add_argument(
        "--threshold",
        type=number(0.0, 1.0),
        help="least grounding probability to place against (default: the policy's)",
    )
    model.add_argument(
        "--decision",
        choices=DECISION_MODES,
        help="how each reference's token is chosen: argmax (the paper's) or joint (the most probable assignment "
        "that admits a placement, docs/policy.md); default: a --policy folder's, else the policy's",
    )
    model.add_argument(
        "--top-k",
        type=count(1, MAX_TOP_K),
        help="the joint decision's candidate tokens per reference (default: a --policy folder's, else the policy's)",
    )
    model.add_argument("--samples", type=count(1, MAX_SAMPLES), default=1024, help="placements to sample")
    model.add_argument("--seed", type=count(0, MAX_SEED), default=0, help="seed of the placement samples (default 0)")
    parser.add_argument("--out", type=Path, default=Path("place.png"), help="figure to write (PNG)")
    parser.set_defaults(func=run_place)


def run_place(args: argparse.Namespace) -> int:
    import jax

    from ocplace.errors import PolicyInputError
    from ocplace.models.inference_settings import Decision
    from ocplace.models.parsing import make_parser
    from ocplace.models.placement.sampler import SamplerConfig
    from ocplace.models.policy import PlacementPolicy, check_scene
    from ocplace.models.policy_figure import save_placement_figure

    # Everything given is read and checked before the backbone loads, which takes seconds to minutes.
    if args.top_k is not None and (problems := Decision("joint", args.top_k).problems()):
        raise PolicyInputError("; ".join(problems))
    scene, record = _scene(args)
    check_scene(scene)  # sizes that disagree, the camera, the footprint
    if args.policy is not None:
        from ocplace.models.policy_folder import read_policy_config

        settings = read_policy_config(args.policy).get("policy")  # a damaged one fails typed when loaded below
        recorded = settings.get("parser") if isinstance(settings, dict) else None
        parser = make_parser(args.parser or recorded or "offline")
    else:
        parser = make_parser(args.parser or "offline")
    parser.parse(scene.instruction)  # the policy parses it again: a few milliseconds, or the LLM parser's cache
    kwargs: dict[str, Any] = {"sampler": SamplerConfig(num_samples=args.samples)}
    if args.threshold is not None:
        kwargs["threshold"] = args.threshold
    if args.policy is not None:
        if args.adapters is not None:
            raise PolicyInputError("--policy holds its adapters: drop --adapters")
        # --backbone says where a CLIP folder's checkpoint is now; a folder with its own backbone refuses it.
        policy = PlacementPolicy.from_pretrained(args.policy, parser=parser, checkpoint=args.backbone)
        sampler = dataclasses.replace(policy.sampler, num_samples=args.samples)  # the folder's, but the count
        policy = dataclasses.replace(policy, sampler=sampler, threshold=kwargs.get("threshold", policy.threshold))
    else:
        from ocplace.methods.ours.method import placement_policy

        if args.adapters is None:
            print("no --adapters given: zero-shot grounding (plain backbone similarity, 'Ours w/o Adapter')")
        policy = placement_policy(args.adapters, args.backbone, parser, **kwargs)
    if args.decision is not None or args.top_k is not None:
        chosen = Decision(args.decision or policy.decision.mode, args.top_k or policy.decision.top_k)
        policy = dataclasses.replace(policy, decision=chosen)  # refused (ConfigError) past the joint search's size
    [placement] = policy.place_many([scene], jax.random.key(args.seed))
    print(placement.summary())
    if record is not None:
        _compare_with_truth(placement, record)
    save_placement_figure(placement, scene, args.out)  # last: a full disk costs the picture, not the placement
    print(f"wrote {args.out}")
    return 0 if placement.error is None else 2


def _scene(args):
    from ocplace.errors import PolicyInputError

    if args.instruction is not None and not args.instruction.strip():
        raise PolicyInputError(
            "--instruction is empty; say where to put the object, e.g. --instruction "
            '"put it to the left of the red bowl", or leave it out to use a dataset scene\'s own'
        )
    if args.dataset is not None:
        own = [flag for flag, value in OWN_IMAGE_FLAGS.items() if getattr(args, value) is not None]
        if own:  # a dataset scene has its own: these would be ignored without a word
            raise PolicyInputError(f"{', '.join(own)} describe your own images; a --dataset scene has its own")
        return _dataset_scene(args)
    if args.rgb is None or args.depth is None or args.instruction is None:
        raise PolicyInputError("give --dataset DIR --id K, or --rgb, --depth and --instruction")
    return _image_scene(args), None


def _dataset_scene(args):
    import dataclasses

    from ocplace.errors import DatasetError
    from ocplace.methods.policy_method import scene_input
    from ocplace.sim.dataset.job import listed_scenes

    if args.id is None:
        raise DatasetError("--dataset needs --id (a scene id such as seen-00003, or an index within --split)")
    scenes = listed_scenes(args.dataset, args.split)
    if args.id.isdigit():
        if int(args.id) >= len(scenes):
            raise DatasetError(f"split {args.split!r} has {len(scenes)} scenes; --id {args.id} is out of range")
        listed = scenes[int(args.id)]
    else:
        matches = [scene for scene in scenes if scene.name == args.id]
        if not matches:
            raise DatasetError(f"no scene {args.id!r} in split {args.split!r} of {args.dataset}")
        listed = matches[0]
    record = listed.read()
    scene = scene_input(record)
    if args.detect:
        scene = dataclasses.replace(scene, boxes_or_segmentation=None, object_aabbs=None)
    if args.instruction is not None:
        scene = dataclasses.replace(scene, instruction=args.instruction)
    return scene, record


def _image_scene(args):
    from ocplace.models.scene_files import read_scene_input
    from ocplace.sim.camera import DEFAULT_CAMERA

    if args.camera is None:
        print("no --camera given: assuming the simulator's camera (640x480, 70 deg, 0.6 m above the table)")
    return read_scene_input(
        args.rgb,
        args.depth,
        args.segmentation,
        args.camera or DEFAULT_CAMERA,
        args.instruction,
        tuple(args.held_footprint or HELD_FOOTPRINT),
    )


def _compare_with_truth(placement, record) -> None:
    """The dataset's ground truth beside the placement (for inspection; the policy never reads it)."""
    import numpy as np

    from ocplace.sim import metric

    truth = "; ".join(f"<{t.reference_name}, {t.relation}> token {t.token_index}" for t in record.tuples)
    print(f"  ground truth: {truth}")
    if placement.mode is not None:
        success = bool(metric.placement_success(np.asarray(placement.mode)[None], record.problem())[0])
        rate = float(np.mean(metric.placement_success(placement.samples, record.problem())))
        print(f"  benchmark metric: mode {'succeeds' if success else 'fails'}; {rate:.1%} of samples succeed")
