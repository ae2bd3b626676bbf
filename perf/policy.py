"""Latency of one `PlacementPolicy.place` call, stage by stage, after compilation.

Stages: parse (offline parser), prepare (checks, N crops + the workspace image cut at 224 px),
encode (N + 1 images and L phrases through the backbone; images and texts also timed alone),
ground (adapters + softmax), sample (1024 placements, one scene), and the whole `place` call.
Backbones: the offline backbone (`--offline SPEC`; by default random weights of the default
architecture, which cost the same as trained ones) and a ViT-B/32-sized Flax CLIP with random
weights and a byte-level CLIP-format tokenizer written on the spot (no download). The scene is a
2-reference scene of a dataset.
Usage: `python perf/policy.py --dataset DIR [--repeats 20] [--size tiny]` (tiny: smoke-size models,
to try the script).
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
import os
import statistics
import tempfile
import time
from pathlib import Path

import jax
import numpy as np

from ocplace.models.backbone import ClipBackbone, ImagePreprocessing, random_clip_params
from ocplace.models.placement.sampler import SamplerConfig
from ocplace.models.policy import PlacementPolicy, load_backbone_spec
from ocplace.vocabulary import CLIP_IMAGE_MEAN, CLIP_IMAGE_STD

VIT_B32 = dict(
    text_config=dict(
        hidden_size=512,
        intermediate_size=2048,
        num_hidden_layers=12,
        num_attention_heads=8,
        max_position_embeddings=77,
        vocab_size=49408,
    ),
    vision_config=dict(
        image_size=224,
        patch_size=32,
        hidden_size=768,
        intermediate_size=3072,
        num_hidden_layers=12,
        num_attention_heads=12,
    ),
    projection_dim=512,
)
TINY_CLIP = dict(
    text_config=dict(
        hidden_size=32,
        intermediate_size=64,
        num_hidden_layers=2,
        num_attention_heads=2,
        max_position_embeddings=16,
        vocab_size=49408,
    ),
    vision_config=dict(
        image_size=32, patch_size=8, hidden_size=32, intermediate_size=64, num_hidden_layers=2, num_attention_heads=2
    ),
    projection_dim=16,
)


def byte_level_tokenizer(directory: Path):
    """A CLIP-format tokenizer with CLIP's byte alphabet and no merges, written to `directory`.

    Texts are padded to the model's context length, so the tower costs what it costs with
    OpenAI's 49,408-token vocabulary.
    """
    from transformers import CLIPTokenizerFast
    from transformers.models.clip.tokenization_clip import bytes_to_unicode

    bos, eos = "<|startoftext|>", "<|endoftext|>"
    chars = list(bytes_to_unicode().values())
    vocab = [*chars, *(c + "</w>" for c in chars), bos, eos]  # end token last, as in OpenAI's vocabulary
    directory.mkdir(parents=True, exist_ok=True)
    (directory / "vocab.json").write_text(json.dumps({token: i for i, token in enumerate(vocab)}))
    (directory / "merges.txt").write_text("#version: 0.2\n")
    return CLIPTokenizerFast(
        vocab_file=str(directory / "vocab.json"),
        merges_file=str(directory / "merges.txt"),
        bos_token=bos,
        eos_token=eos,
        pad_token=eos,
        unk_token=eos,
    )


def random_clip_backbone(sizes: dict, directory: Path) -> ClipBackbone:
    """A Flax CLIP of `sizes` with random weights and a byte-level tokenizer."""
    from transformers import CLIPConfig, FlaxCLIPModel

    tokenizer = byte_level_tokenizer(directory)
    ids = dict(
        bos_token_id=tokenizer.bos_token_id, eos_token_id=tokenizer.eos_token_id, pad_token_id=tokenizer.eos_token_id
    )
    config = CLIPConfig(
        text_config={**sizes["text_config"], **ids},
        vision_config=sizes["vision_config"],
        projection_dim=sizes["projection_dim"],
    )
    model = FlaxCLIPModel(config, _do_init=False)
    size = sizes["vision_config"]["image_size"]
    prep = ImagePreprocessing(size, (size, size), CLIP_IMAGE_MEAN, CLIP_IMAGE_STD, resample=3)
    return ClipBackbone(model, random_clip_params(model.params_shape_tree, seed=0), tokenizer, prep, source="random")


def random_offline_backbone(tiny: bool):
    from ocplace.models import offline_backbone as ob

    config = ob.smoke_config() if tiny else ob.default_config()
    return ob.OfflineBackbone(config, ob.init_params(config, jax.random.key(0)), source="random")


def pick_scene(dataset: Path):
    """The first seen scene with the most references (2obj) and boxes: `(policy input, true tokens)`."""
    from ocplace.eval.ours import scene_input
    from ocplace.sim.dataset.job import scene_dirs
    from ocplace.sim.dataset.records import read_scene

    records = [read_scene(d) for d in scene_dirs(dataset, "seen")[:40]]
    record = max(records, key=lambda r: (len(r.meta["tuples"]), len(r.meta["boxes"])))
    return scene_input(record), [t.token_index for t in record.tuples]


@dataclasses.dataclass(frozen=True)
class TrueTokenPolicy(PlacementPolicy):
    """Computes the grounding as usual but places against the true tokens: random weights would
    ground wrongly, and a scene with an empty feasible region would time the error path instead."""

    true_tokens: tuple[int, ...] = ()

    def decide(self, scene, parsed, probabilities):
        forced = np.zeros_like(np.asarray(probabilities))
        forced[np.arange(len(self.true_tokens)), self.true_tokens] = 1.0
        return super().decide(scene, parsed, forced)


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
            lambda: policy.sample([prepared], [references], key)[0], repeats
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
            "offline" + ("" if args.offline else " (random weights)"): load_backbone_spec(args.offline)
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
