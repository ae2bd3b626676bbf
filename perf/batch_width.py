"""Benchmark: the offline backbone's image tower by batch width (issue 42, Raw Image Grids' featurisation).

    python perf/batch_width.py [--images 384] [--repeats 3]

The default recipe's architecture with random weights (the time does not depend on the values), 160 px
images, `OfflineBackbone.encode_images` at each `max_batch` after compiling it; prints the median ms per
image over the passes and the ratio to the shipped width (64).
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

WIDTHS = (8, 16, 24, 32, 48, 64, 128)
SHIPPED = 64


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--images", type=int, default=384)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    import jax

    from ocplace.models import offline_backbone as ob
    from ocplace.models.offline_config import default_config

    config = default_config()
    backbone = ob.OfflineBackbone(
        config, ob.init_params(config, jax.random.key(0)), ob.FrozenTextTower.load(config.text_max_length)
    )
    size = config.image_size
    images = np.random.default_rng(0).integers(0, 256, (args.images, size, size, 3), dtype=np.uint8)
    per_image = {}
    for width in WIDTHS:
        backbone.max_batch = width
        backbone.encode_images(images[:width])  # compile this width
        passes = []
        for _ in range(args.repeats):
            start = time.perf_counter()
            backbone.encode_images(images)
            passes.append((time.perf_counter() - start) / args.images * 1e3)
        per_image[width] = statistics.median(passes)
    print(f"{args.images} images of {size} px, median of {args.repeats} passes")
    for width, ms in per_image.items():
        print(f"max_batch {width:4d}  {ms:6.2f} ms/image  ({ms / per_image[SHIPPED]:.2f} of the shipped {SHIPPED})")


if __name__ == "__main__":
    main()
