"""Image encoding throughput of an image tower against the machine's matmul roofline.

Towers: `--tower clip`, a ViT-B/32-sized Flax CLIP (random weights, built here, no download), or
`--tower offline`, the default offline backbone's (EfficientNet-Lite0 with its ImageNet weights,
128 px, + projection). Measures, in the same run: (1) the jitted image tower (normalisation +
trunk + projection + L2 norm) in images/s at batch 32 on its input size; (2) host-side
preprocessing (PIL bicubic resize + centre crop) of 224 x 224 crops and of 640 x 480 frames;
(3) a dense-matmul roofline: a square `jnp.dot` of about the same FLOPs as one batch, whose
achieved FLOP/s is the machine's practical peak. FLOPs of the model come from XLA's cost analysis.
Usage: `python perf/featurize.py [--tower clip|offline] [--batch 32] [--repeats 3]`.
"""

from __future__ import annotations

import argparse
import datetime
import os
import time

import jax
import jax.numpy as jnp
import numpy as np
from random_clip import VIT_B32, clip_preprocessing, random_clip_model

from ocplace.models.backbone import normalize_pixels, resize_and_crop
from ocplace.models.grounding import l2_normalize


def best_seconds(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - start)
    return min(times)


def clip_tower():
    model, params = random_clip_model(VIT_B32)
    prep = clip_preprocessing(VIT_B32)
    encode = jax.jit(lambda p, x: l2_normalize(model.get_image_features(normalize_pixels(x, prep), params=p)))
    return encode, jax.device_put(params), prep, "ViT-B/32"


def offline_tower():
    import functools

    from ocplace.models import offline_backbone as ob
    from ocplace.models import offline_config

    config = offline_config.default_config()
    params = jax.device_put(ob.init_params(config, jax.random.key(0)))
    encode = jax.jit(functools.partial(ob.image_embeddings, config))
    return encode, params, config.preprocessing, f"offline (EfficientNet-{config.trunk}, {config.image_size} px)"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=32)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--tower", choices=("clip", "offline"), default="clip")
    args = parser.parse_args()

    encode, params, prep, name = clip_tower() if args.tower == "clip" else offline_tower()
    rng = np.random.default_rng(0)
    size = prep.crop[0]
    pixels = jnp.asarray(rng.integers(0, 256, (args.batch, size, size, 3), dtype=np.uint8))
    print(
        f"{datetime.datetime.now():%Y-%m-%d %H:%M}, {os.cpu_count()} CPUs, load average "
        f"{' '.join(f'{x:.1f}' for x in os.getloadavg())} (other jobs share this machine)"
    )

    start = time.perf_counter()
    compiled = encode.lower(params, pixels).compile()
    compile_s = time.perf_counter() - start
    flops = float(compiled.cost_analysis()["flops"])
    model_s = best_seconds(lambda: compiled(params, pixels), args.repeats)

    n = int(round((flops / 2) ** (1 / 3) / 128)) * 128  # square dot with 2 n^3 ~ one batch's FLOPs
    a = jnp.asarray(rng.normal(size=(n, n)).astype(np.float32))
    b = jnp.asarray(rng.normal(size=(n, n)).astype(np.float32))
    dot = jax.jit(jnp.dot)
    jax.block_until_ready(dot(a, b))
    dot_s = best_seconds(lambda: dot(a, b), args.repeats)
    dot_flops = 2.0 * n**3

    crops = rng.integers(0, 256, (args.batch, 224, 224, 3), dtype=np.uint8)
    frames = rng.integers(0, 256, (8, 480, 640, 3), dtype=np.uint8)
    crop_s = best_seconds(lambda: [resize_and_crop(c, prep) for c in crops], args.repeats) / len(crops)
    frame_s = best_seconds(lambda: [resize_and_crop(f, prep) for f in frames], args.repeats) / len(frames)

    model_rate, dot_rate = flops / model_s, dot_flops / dot_s
    print(
        f"{name} image tower, batch {args.batch}: {args.batch / model_s:6.1f} images/s "
        f"({model_s:.2f} s per batch, compile {compile_s:.1f} s not counted)"
    )
    print(f"  {flops / args.batch / 1e9:.2f} GFLOP per image (XLA cost analysis); {model_rate / 1e9:.1f} GFLOP/s")
    print(
        f"dense matmul roofline: jnp.dot {n}x{n} @ {n}x{n} ({dot_flops / 1e9:.0f} GFLOP): {dot_rate / 1e9:.1f} GFLOP/s"
    )
    print(f"image tower at {100 * model_rate / dot_rate:.0f}% of the matmul roofline")
    print(
        f"host preprocessing to {size} px: {1 / crop_s:7.0f} crops/s (224x224), {1 / frame_s:6.0f} frames/s (640x480)"
    )


if __name__ == "__main__":
    main()
