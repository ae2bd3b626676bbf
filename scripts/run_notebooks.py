"""Execute the notebooks on what `make demo` wrote (`make notebooks`), saving each executed copy beside `--out`.

Runs from the repository's root with the notebooks' own defaults (out/demo); stops at the first error.
"""

import argparse
import sys
from pathlib import Path

import nbformat
from nbclient import NotebookClient

ROOT = Path(__file__).resolve().parent.parent
NOTEBOOKS = ("01_grounding_logits.ipynb", "02_results.ipynb")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=ROOT / "out" / "demo" / "notebooks", help="executed copies")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    for name in NOTEBOOKS:
        notebook = nbformat.read(ROOT / "notebooks" / name, as_version=4)
        where = {"metadata": {"path": str(ROOT)}}  # the kernel starts in the root, as `make` runs
        NotebookClient(notebook, timeout=1800, kernel_name="python3", resources=where).execute()
        nbformat.write(notebook, args.out / name)
        print(f"executed {name} -> {args.out / name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
