"""Benchmark: w/o CLIP pre-train's batch-norm calibration, fused (jitted, shipped) against op by op.

    python perf/calibration.py [--images 256] [--size 160]

Each way runs in a fresh process (its own compilation, its own peak memory) on the same random images
through the same random lite0 trunk; prints each one's seconds and peak RSS, the ratio, and the largest
difference of a statistic: a variance relative, a mean in units of its channel's standard deviation.
"""

from __future__ import annotations

import argparse
import inspect
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def _run(mode: str, images: int, size: int, out: Path) -> None:
    import jax

    from ocplace.models import efficientnet

    variables = efficientnet.init(jax.random.key(0))
    pixels = np.random.default_rng(0).integers(0, 256, (images, size, size, 3), dtype=np.uint8)
    calibrate = efficientnet.calibrate_batch_stats
    start = time.perf_counter()
    stats = (calibrate if mode == "fused" else inspect.unwrap(calibrate))(variables, pixels)["batch_stats"]
    jax.block_until_ready(stats)
    seconds = time.perf_counter() - start
    leaves = {jax.tree_util.keystr(p): np.asarray(x) for p, x in jax.tree_util.tree_leaves_with_path(stats)}
    np.savez(out / f"{mode}.npz", **leaves)  # type: ignore[arg-type]  # numpy's stub takes a key for allow_pickle
    peak_gb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6
    (out / f"{mode}.json").write_text(json.dumps({"seconds": seconds, "peak_gb": peak_gb}))


def _largest_differences(op: dict, fused: dict) -> tuple[float, float]:
    variance, mean = 0.0, 0.0
    for key in op:
        a, b = op[key].astype(np.float64), fused[key].astype(np.float64)
        if key.endswith("['var']"):
            variance = max(variance, float(np.max(np.abs(a - b) / a)))
        else:
            std = np.sqrt(op[key.replace("['mean']", "['var']")].astype(np.float64))
            mean = max(mean, float(np.max(np.abs(a - b) / std)))
    return variance, mean


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--images", type=int, default=256)
    parser.add_argument("--size", type=int, default=160)
    parser.add_argument("--mode", choices=("op", "fused"), help=argparse.SUPPRESS)
    parser.add_argument("--out", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.mode:
        _run(args.mode, args.images, args.size, args.out)
        return
    with tempfile.TemporaryDirectory() as folder:
        out = Path(folder)
        for mode in ("op", "fused"):
            command = [sys.executable, __file__, "--mode", mode, "--images", str(args.images), "--size", str(args.size)]
            subprocess.run([*command, "--out", str(out)], check=True)
        op, fused = (json.loads((out / f"{m}.json").read_text()) for m in ("op", "fused"))
        with np.load(out / "op.npz") as a, np.load(out / "fused.npz") as b:
            variance, mean = _largest_differences(dict(a), dict(b))
    print(f"{args.images} images of {args.size} px through a random lite0 trunk, each way in a fresh process")
    print(f"op by op  {op['seconds']:6.1f} s  peak RSS {op['peak_gb']:.2f} GB")
    ratio = op["seconds"] / fused["seconds"]
    print(f"fused     {fused['seconds']:6.1f} s  peak RSS {fused['peak_gb']:.2f} GB  ({ratio:.1f}x faster)")
    print(f"largest difference: variance {variance:.1e} relative, mean {mean:.1e} of its channel's std (bound 1e-5)")


if __name__ == "__main__":
    main()
