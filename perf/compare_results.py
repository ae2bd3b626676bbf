"""Whether two `results.json` files hold the same results: everything the code decides, not when or where.

    python perf/compare_results.py OLD/results.json NEW/results.json [--map OLD_TEXT=NEW_TEXT ...] [--drop KEY ...]

Dropped before comparing: the date, the command line, the environment, the pipeline's echo of its
own config and every wall time. Each file's output folder is replaced by `OUT`; `--map` replaces
more text in the old file (a cache root, a renamed file) so that known, intended differences do not
hide the rest; `--drop` leaves out more keys wherever they stand (`description`: what each method
recorded of itself, its recipe and its files' hashes, when a change only reshapes how recipes are
recorded; then compare the weights with `perf/compare_weights.py`). Prints IDENTICAL or the first
differences; exit status 0 or 1.
"""

import argparse
import json
import sys
from pathlib import Path

DROPPED = {"created", "environment", "command", "pipeline", "wall_s"}


def cleaned(node, out: str, dropped: frozenset[str] = frozenset(DROPPED)):
    if isinstance(node, dict):
        return {key: cleaned(value, out, dropped) for key, value in node.items() if key not in dropped}
    if isinstance(node, list):
        return [cleaned(value, out, dropped) for value in node]
    return node.replace(out, "OUT") if isinstance(node, str) else node


def differences(old, new, where: str = "") -> list[str]:
    if type(old) is not type(new) or not isinstance(old, dict | list):
        return [] if old == new else [f"{where}: {str(old)[:80]} != {str(new)[:80]}"]
    if isinstance(old, list):
        found = [f"{where}: {len(old)} != {len(new)} items"] if len(old) != len(new) else []
        return found + [line for i, pair in enumerate(zip(old, new)) for line in differences(*pair, f"{where}[{i}]")]
    found = [f"{where}.{key}: only in one file" for key in sorted(set(old) ^ set(new))]
    shared = sorted(set(old) & set(new))
    return found + [line for key in shared for line in differences(old[key], new[key], f"{where}.{key}")]


def load(path: Path, replacements: list[tuple[str, str]], dropped: frozenset[str]):
    text = path.read_text()
    for before, after in replacements:
        text = text.replace(before, after)
    return cleaned(json.loads(text), str(path.resolve().parent), dropped)


def _replacement(pair: str) -> tuple[str, str]:
    before, equals, after = pair.partition("=")
    if not before or not equals:
        raise argparse.ArgumentTypeError(f"--map takes OLD=NEW, not {pair!r}")
    return before, after


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("old", type=Path)
    parser.add_argument("new", type=Path)
    parser.add_argument(
        "--map", action="append", default=[], type=_replacement, metavar="OLD=NEW", help="text to replace in OLD"
    )
    parser.add_argument("--drop", action="append", default=[], metavar="KEY", help="a key to leave out everywhere")
    args = parser.parse_args()
    dropped = frozenset(DROPPED | set(args.drop))
    found = differences(load(args.old, args.map, dropped), load(args.new, [], dropped))
    print("IDENTICAL" if not found else f"DIFFERENT ({len(found)} places)")
    for line in found[:40]:
        print("  ", line)
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())
