"""Whether two `reproduce` outputs trained the same weights: every tensor of every run's weights files, bit for bit.

    python perf/compare_weights.py OLD/runs NEW/runs

Each `*.safetensors` under OLD (checkpoints left out) is compared with the file at the same place under NEW:
the same tensor names, and each tensor equal in shape, dtype and every bit. A file's metadata (what it recorded
of its recipe) is not compared. Prints one line per file and IDENTICAL or DIFFERENT; exit status 0 or 1.
"""

import argparse
import sys
from pathlib import Path

import numpy as np
from safetensors.numpy import load_file


def same_tensors(old: Path, new: Path) -> bool:
    if not new.is_file():
        return False
    before, after = load_file(str(old)), load_file(str(new))
    return before.keys() == after.keys() and all(
        before[name].dtype == after[name].dtype and np.array_equal(before[name], after[name]) for name in before
    )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("old", type=Path)
    parser.add_argument("new", type=Path)
    args = parser.parse_args()
    files = [path for path in sorted(args.old.rglob("*.safetensors")) if "checkpoints" not in path.parts]
    verdicts = {path.relative_to(args.old): same_tensors(path, args.new / path.relative_to(args.old)) for path in files}
    for path, same in verdicts.items():
        print(f"{path}: {'same tensors' if same else 'DIFFERENT'}")
    identical = bool(verdicts) and all(verdicts.values())
    print(f"{'IDENTICAL' if identical else 'DIFFERENT'} ({len(verdicts)} weights files)")
    return 0 if identical else 1


if __name__ == "__main__":
    sys.exit(main())
