"""Latency of one `PlacementPolicy.place` call, stage by stage, after compilation.

Stages: parse (offline parser), prepare (checks, N crops + the workspace image cut at 224 px),
encode (N + 1 images and L phrases through the backbone; images and texts also timed alone),
ground (adapters + softmax), sample (1024 placements, one scene), and the whole `place` call.
Backbones: the offline backbone (`--offline SPEC`; by default random weights of the default
architecture, which cost the same as trained ones) and a ViT-B/32-sized Flax CLIP with random
weights and a byte-level CLIP-format tokenizer written on the spot (`perf/random_clip.py`, no download). The scene is a
2-reference scene of a dataset.
Usage: `python perf/policy.py --dataset DIR [--repeats 20] [--size tiny]` (tiny: smoke-size models,
to try the script).
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import os
import statistics
import tempfile
import time
from pathlib import Path

import jax
import numpy as np
from random_clip import TINY_CLIP, VIT_B32, random_clip_backbone

from ocplace.models.backbone import load_backbone
from ocplace.models.placement.sampler import SamplerConfig
from ocplace.models.policy import PlacementPolicy, SceneProgress


def random_offline_backbone(tiny: bool):
    from ocplace.models import offline_backbone as ob
    from ocplace.models import offline_config

    config = offline_config.smoke_config() if tiny else offline_config.default_config()
    return ob.OfflineBackbone(config, ob.init_params(config, jax.random.key(0)), source="random")


def pick_scene(dataset: Path):
    """The first seen scene with the most references (2obj) and boxes: `(policy input, true tokens)`."""
    from ocplace.methods.policy_method import scene_input
    from ocplace.sim.dataset.job import listed_scenes

    records = [scene.read() for scene in listed_scenes(dataset, "seen")[:40]]
    record = max(records, key=lambda r: (len(r.true_tuples()), len(r.boxes)))
    return scene_input(record), [t.token_index for t in record.true_tuples()]


@dataclasses.dataclass(frozen=True)
class TrueTokenPolicy(PlacementPolicy):
    """Computes the grounding as usual but places against the true tokens: random weights would
    ground wrongly, and a scene with an empty feasible region would time the error path instead."""

    true_tokens: tuple[int, ...] = ()

    def decide(self, scene, parsed, probabilities, tokens=None):
        return super().decide(scene, parsed, probabilities, self.true_tokens)


def median_ms(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - start)
    return 1000.0 * statistics.median(times)


def stage_times(policy: PlacementPolicy, scene, repeats: int) -> dict[str, float]:
    key = jax.random.key(0)

    def place():
        return policy.place(
            scene.rgb,
            scene.depth,
            scene.boxes_or_segmentation,
            scene.instruction,
            scene.held_footprint,
            key,
            camera=scene.camera,
            object_aabbs=scene.object_aabbs,
        )

    start = time.perf_counter()
    place()  # compiles everything once
    first_s = time.perf_counter() - start
    prepared = policy.prepare(scene)
    parsed = policy.parse(scene.instruction)
    tokens = policy.encode([prepared], [parsed])
    references = policy.decide(prepared, parsed, policy.ground(tokens)[0])
    images = list(prepared.crops) + [prepared.workspace]
    texts = [policy.prompt.text_for(t.reference) for t in parsed]
    return {
        "parse": median_ms(lambda: policy.parse(scene.instruction), repeats),
        "prepare (crops, workspace)": median_ms(lambda: policy.prepare(scene), repeats),
        f"encode {len(images)} images + {len(texts)} texts": median_ms(
            lambda: policy.encode([prepared], [parsed]), repeats
        ),
        "  images alone": median_ms(lambda: policy.backbone.encode_images(np.stack(images)), repeats),
        "  texts alone": median_ms(lambda: policy.backbone.encode_texts(texts), repeats),
        "ground": median_ms(lambda: policy.ground(tokens), repeats),
        f"sample {policy.sampler.num_samples}": median_ms(
            lambda: policy.sample([SceneProgress(scene, prepared, parsed, references)], key), repeats
        ),
        "place (end to end)": median_ms(place, repeats),
        "first place call (compiles)": first_s * 1000.0,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", type=Path, required=True)
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--size", choices=("paper", "tiny"), default="paper")
    parser.add_argument("--offline", help="offline backbone spec (default: random weights, default architecture)")
    args = parser.parse_args()

    from ocplace.models.parsing import make_parser

    tiny = args.size == "tiny"
    scene, true_tokens = pick_scene(args.dataset)
    text_parser = make_parser("offline")
    print(
        f"{datetime.datetime.now():%Y-%m-%d %H:%M}, {os.cpu_count()} CPUs, load average "
        f"{' '.join(f'{x:.1f}' for x in os.getloadavg())} (other jobs share this machine)"
    )
    print(f"scene {scene.name}: {len(scene.boxes_or_segmentation)} boxes, {scene.instruction!r}")
    with tempfile.TemporaryDirectory() as tmp:
        backbones = {
            "offline" + ("" if args.offline else " (random weights)"): load_backbone(args.offline)
            if args.offline
            else random_offline_backbone(tiny),
            ("tiny CLIP" if tiny else "ViT-B/32 CLIP") + " (random weights)": random_clip_backbone(
                TINY_CLIP if tiny else VIT_B32, Path(tmp)
            ),
        }
        for name, backbone in backbones.items():
            policy = TrueTokenPolicy(
                **vars(
                    PlacementPolicy.from_run(backbone, None, parser=text_parser, sampler=SamplerConfig(), threshold=0.0)
                ),
                true_tokens=tuple(true_tokens),
            )
            print(f"\n{name}, D = {backbone.dim}: median of {args.repeats} calls, ms")
            for stage, ms in stage_times(policy, scene, args.repeats).items():
                print(f"  {stage:<36} {ms:9.1f}")


if __name__ == "__main__":
    main()
