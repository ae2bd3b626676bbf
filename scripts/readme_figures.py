"""Write the demo's Table I figures into README.md from a fresh run's results (`make demo`'s out/demo/results.json).

The README holds the block between `<!-- demo-table -->` and `<!-- /demo-table -->`; this script rewrites it
(overall success of the mode per test subset, one row per method on the whole training set, averaged over
seeds), so that the figures a new user compares with are a run's, never typed by hand.
"""

import argparse
import re
import sys
from pathlib import Path

from ocplace.eval.results import read_results
from ocplace.eval.statistics import full_runs, repeats
from ocplace.vocabulary import TEST_SUBSETS

ROOT = Path(__file__).resolve().parent.parent
BEGIN, END = "<!-- demo-table -->", "<!-- /demo-table -->"
NAMES = {"seen": "Seen", "unseen_obj": "Unseen obj", "unseen_inst": "Unseen inst", "unseen_cat": "Unseen cat"}


def demo_table(results: dict, source: str) -> str:
    """The block's markdown: one row per label, the mean overall success (%) of its whole-training-set runs."""
    subsets = [s for s in TEST_SUBSETS if s in results["settings"]["subsets"]]
    rows = {
        entry["label"]: [[run["subsets"][s]["aggregate"]["overall"]["success"] for s in subsets] for run in runs]
        for entry in full_runs(results)
        for runs in [repeats(results, entry)]
    }
    git = results["environment"].get("git") or {}
    made = f"`{git.get('commit', '?')[:7]}`{' (modified)' if git.get('dirty') else ''}, {results['created'][:10]}"
    lines = [
        f"| `make demo` ({made}) | " + " | ".join(NAMES[s] for s in subsets) + " |",
        "| --- | " + " | ".join("---:" for _ in subsets) + " |",
    ]
    for label, runs in rows.items():
        means = [100 * sum(run[i] for run in runs) / len(runs) for i in range(len(subsets))]
        lines.append(f"| {label} | " + " | ".join(f"{m:.1f}" for m in means) + " |")
    threshold = results["settings"].get("threshold", 0.0)
    protocol = "the paper's protocol (always placed)" if threshold == 0 else f"refused below P {threshold:g}"
    note = f"Overall success of the mode (%), {protocol}; from `{source}` by `scripts/readme_figures.py`."
    return "\n".join([BEGIN, *lines, "", note, END])


def rewrite(readme: str, block: str) -> str:
    if BEGIN not in readme or END not in readme:
        raise SystemExit(f"README has no {BEGIN} ... {END} block to write into")
    return re.sub(re.escape(BEGIN) + ".*?" + re.escape(END), lambda _: block, readme, count=1, flags=re.S)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("results", type=Path, nargs="?", default=Path("out/demo/results.json"))
    parser.add_argument("--readme", type=Path, default=ROOT / "README.md")
    args = parser.parse_args()
    block = demo_table(read_results(args.results), str(args.results))
    args.readme.write_text(rewrite(args.readme.read_text(), block))
    print(block)
    return 0


if __name__ == "__main__":
    sys.exit(main())
