"""Dataset generation throughput: scenes/s with 1 and 2 workers, and the size on disk.

`python perf/generate.py` times a prefix of the default dataset with each worker count, then
(with `--full`) the whole default dataset (3200 scenes) with the largest worker count.
"""

from __future__ import annotations

import argparse
import dataclasses
import shutil
import tempfile
import time
from pathlib import Path

import ocplace  # noqa: F401  (sets the headless OpenGL default before MuJoCo loads)
from ocplace.runtime import ExecutorConfig, open_executor
from ocplace.sim.dataset.config import default_config, make_config
from ocplace.sim.dataset.job import generate_dataset


def timed(out: Path, config, workers: int) -> tuple[float, dict]:
    start = time.perf_counter()
    with open_executor(ExecutorConfig(workers=workers)) as executor:
        manifest = generate_dataset(out, config, executor=executor, progress=False)
    return time.perf_counter() - start, manifest


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=120, help="training scenes per worker-count run")
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--full", action="store_true", help="also generate the full default dataset")
    parser.add_argument("--out", type=Path, help="keep the full dataset here (default: a temporary folder)")
    args = parser.parse_args()

    prefix = make_config(train=args.scenes)
    prefix = dataclasses.replace(prefix, splits=prefix.splits[:1])
    with tempfile.TemporaryDirectory() as tmp:
        for workers in args.workers:
            seconds, manifest = timed(Path(tmp) / f"w{workers}", prefix, workers)
            print(
                f"{workers} worker(s): {args.scenes} scenes in {seconds:.1f} s = {args.scenes / seconds:.2f} scenes/s "
                f"(process start and arena compile included), "
                f"{manifest['statistics']['bytes'] / args.scenes / 1e6:.2f} MB/scene"
            )
        if args.full:
            out = args.out or Path(tmp) / "full"
            seconds, manifest = timed(out, default_config(), max(args.workers))
            scenes = sum(sum(c.values()) for c in manifest["counts"].values())
            print(
                f"full default dataset: {scenes} scenes in {seconds / 60:.1f} min with {max(args.workers)} workers, "
                f"{manifest['statistics']['bytes'] / 1e9:.2f} GB, resampled {manifest['statistics']['resamples']}"
            )
            if args.out is None:
                shutil.rmtree(out)


if __name__ == "__main__":
    main()
