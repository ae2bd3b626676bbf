"""Write Table I's figures into README.md from a run's results: the demo's (`make demo`'s out/demo/results.json) or,
with `--paper`, the paper-scale record's.

The README holds the blocks between `<!-- demo-table -->` and `<!-- /demo-table -->`, and between
`<!-- paper-table -->` and `<!-- /paper-table -->`; this script rewrites one (overall success of the mode per test
subset, one row per method on the whole training set, the mean over its runs, and at paper scale their spread), so
that the figures a new user compares with are a run's, never typed by hand. The paper's own row is cited.
"""

import argparse
import re
import sys
from pathlib import Path

from ocplace.eval.results import read_results
from ocplace.eval.statistics import full_runs, repeats
from ocplace.eval.table import spread
from ocplace.vocabulary import TEST_SUBSETS

ROOT = Path(__file__).resolve().parent.parent
BEGIN, END = "<!-- demo-table -->", "<!-- /demo-table -->"
PAPER_BEGIN, PAPER_END = "<!-- paper-table -->", "<!-- /paper-table -->"
# The paper's Table I, Ours (real CLIP ViT-B/32, its objects; no unseen_cat): cited, for comparison.
PAPER_OURS = {"seen": 97.75, "unseen_obj": 87.25, "unseen_inst": 77.10}
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


def paper_table(results: dict, source: str) -> str:
    """The paper-scale block: mean ± sample standard deviation over each row's distinct runs (`repeats`), as Table I
    gives them, and the paper's Ours."""
    subsets = [s for s in TEST_SUBSETS if s in results["settings"]["subsets"]]
    lines = [
        "| paper scale | " + " | ".join(NAMES[s] for s in subsets) + " |",
        "| --- | " + " | ".join("---:" for _ in subsets) + " |",
    ]
    counts = []
    for entry in full_runs(results):
        runs = repeats(results, entry)
        counts.append(len(runs))
        cells = [spread([run["subsets"][s]["aggregate"]["overall"]["success"] for run in runs]) for s in subsets]
        lines.append(f"| {entry['label']} | " + " | ".join(cells) + " |")
    lines.append("| the paper's Ours (real CLIP) | " + " | ".join(f"{PAPER_OURS.get(s, '-')}" for s in subsets) + " |")
    run_count = f"{min(counts)}-{max(counts)}" if min(counts) != max(counts) else f"{max(counts)}"
    note = (
        f"Overall success of the mode (%), the paper's protocol; mean ± sample standard deviation over each row's "
        f"{run_count} distinct runs (a row that learns nothing counts once per backbone); from `{source}` by "
        "`scripts/readme_figures.py --paper`."
    )
    return "\n".join([PAPER_BEGIN, *lines, "", note, PAPER_END])


def rewrite(readme: str, block: str, begin: str = BEGIN, end: str = END) -> str:
    if begin not in readme or end not in readme:
        raise SystemExit(f"README has no {begin} ... {end} block to write into")
    return re.sub(re.escape(begin) + ".*?" + re.escape(end), lambda _: block, readme, count=1, flags=re.S)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("results", type=Path, nargs="?", default=Path("out/demo/results.json"))
    parser.add_argument("--readme", type=Path, default=ROOT / "README.md")
    parser.add_argument("--paper", action="store_true", help="write the paper-scale block instead of the demo's")
    parser.add_argument("--source", help="the file to name as the source (default: the results path)")
    args = parser.parse_args()
    source = args.source or str(args.results)
    if args.paper:
        block = paper_table(read_results(args.results), source)
        text = rewrite(args.readme.read_text(), block, PAPER_BEGIN, PAPER_END)
    else:
        block = demo_table(read_results(args.results), source)
        text = rewrite(args.readme.read_text(), block)
    args.readme.write_text(text)
    print(block)
    return 0


if __name__ == "__main__":
    sys.exit(main())
