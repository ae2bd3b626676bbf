"""Markdown tables from a results JSON: Table I as the paper lays it out, then the diagnostics.

Table I: one row per method (runs on the whole training set), column groups seen / unseen obj /
unseen inst (the paper's), then unseen cat (ours, not in the paper), each with Table / 1 Obj / 2 Obj /
Obj (the object-referenced scenes: 1 Obj and 2 Obj pooled) / Overall success of the mode in percent,
under the paper's protocol (always placed). Markdown has one header row, so the group names form the
header and the level names the first (bold) row. Below it: a 95% interval for every cell, and the
robot's refusal gate as a selective table (eval/statistics.py).

With repeats over seeds (`ocplace reproduce --seeds N`), Table I and the mean-over-samples table
show each cell's mean ± sample standard deviation over the seeds (its interval covers them); the
diagnostic tables, the sample-efficiency table and the figures show the experiment's own seed.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from ocplace.errors import ResultsError
from ocplace.eval.harness import LEVEL_GROUPS, STAGES
from ocplace.eval.results import LEGACY_THRESHOLD, write_results
from ocplace.eval.statistics import COLUMNS, base_runs, derived, full_runs, repeats
from ocplace.paths import write_text_atomic
from ocplace.vocabulary import PAPER_SUBSETS, SCORED_SPLITS

SUBSET_TITLES = {
    "seen": "Seen",
    "unseen_obj": "Unseen obj",
    "unseen_inst": "Unseen inst",
    "unseen_cat": "Unseen cat (ours, not in the paper)",
    "dev_seen": "Dev seen",
    "dev_colour": "Dev colour",
}
LEVEL_TITLES = {"table": "Table", "1obj": "1 Obj", "2obj": "2 Obj", "objects": "Obj", "overall": "Overall"}
MISSING = "–"
MAX_LISTED_FAILURES = 20


def percent(value: float | None, digits: int = 2) -> str:
    return MISSING if value is None else f"{100 * value:.{digits}f}"


def _row(cells: Sequence[str]) -> str:
    return "| " + " | ".join(markdown_text(cell) for cell in cells) + " |"


def markdown_text(text: object) -> str:
    """`text` on one line with its pipes escaped: a `--label` holding `|` or a newline must not break a table."""
    return " ".join(str(text).split()).replace("|", "\\|")


def spread(values: Sequence[float | None], digits: int = 2) -> str:
    """One value in percent, or the mean and sample standard deviation of several (one per seed)."""
    known = [v for v in values if v is not None]
    if len(known) < 2:
        return percent(known[0] if known else None, digits)
    mean = sum(known) / len(known)
    std = (sum((v - mean) ** 2 for v in known) / (len(known) - 1)) ** 0.5
    return f"{100 * mean:.{digits}f} ± {100 * std:.{digits}f}"


def subset_title(subset: str) -> str:
    """A subset's column title: the benchmark's name for its own, the subset's name for a user catalogue's."""
    return SUBSET_TITLES.get(subset, f"{subset} (your objects)")


def _subsets(results: Mapping[str, Any]) -> list[str]:
    """The evaluated subsets, the benchmark's in their order first, then a user catalogue's as evaluated."""
    evaluated = results["settings"]["subsets"]
    return [s for s in SCORED_SPLITS if s in evaluated] + [s for s in evaluated if s not in SCORED_SPLITS]


def level_table(results: Mapping[str, Any], metric: str, title: str) -> str:
    """Rows = methods; per subset Table / 1 Obj / 2 Obj / Obj (1 and 2 Obj pooled) / Overall of `metric` (an
    aggregate rate) in %; with repeats over seeds, their mean ± sample standard deviation."""
    subsets = _subsets(results)
    columns = COLUMNS
    counts = {len(repeats(results, entry)) for entry in full_runs(results)} or {1}
    note = f" (mean ± standard deviation over {max(counts)} seeds" + (
        ", where a row has them)" if len(counts) > 1 else ")"
    )
    lines = [
        f"**{title}**" + (note if max(counts) > 1 else ""),
        "",
        _row(["", *[subset_title(s) if i == 0 else "" for s in subsets for i in range(len(columns))]]),
        _row(["---", *["---:"] * (len(subsets) * len(columns))]),
        _row(["**Method**", *[f"**{LEVEL_TITLES[c]}**" for _ in subsets for c in columns]]),
    ]
    for entry in full_runs(results):
        cells = [entry["label"]]
        for subset in subsets:
            aggregates = [e["subsets"].get(subset, {}).get("aggregate") for e in repeats(results, entry)]
            cells += [spread([_rate(a, c, metric) for a in aggregates if a]) for c in columns]
        lines.append(_row(cells))
    return "\n".join(lines)


# Said under Table I wherever its unseen_inst column comes from the offline parser.
UNSEEN_INST_NOTE = (
    "Unseen inst with the offline parser is not an independent test of parsing: its lexicon was written in "
    "the same commit as the unseen instruction vocabulary (docs/results.md)."
)


def _rate(aggregate: Mapping[str, Any], column: str, metric: str) -> float | None:
    """A per-scene rate of one Table I column; `objects` pooled from its levels in results written before it
    was stored."""
    if column in aggregate:
        rate: float | None = aggregate[column][metric]
        return rate
    parts = [aggregate[level] for level in LEVEL_GROUPS[column] if level in aggregate]
    scenes = sum(part["scenes"] for part in parts)
    if not scenes or any(part[metric] is None for part in parts if part["scenes"]):
        return None
    return float(sum(part[metric] * part["scenes"] for part in parts if part["scenes"]) / scenes)


def decision_mode(entry: Mapping[str, Any]) -> str | None:
    """How a row's policy chose its tokens (`describe()`'s `policy.decision.mode`); None for a row without one."""
    policy = (entry.get("description") or {}).get("policy")
    decision = policy.get("decision") if isinstance(policy, Mapping) else None
    mode = decision.get("mode") if isinstance(decision, Mapping) else None
    return mode if isinstance(mode, str) else None


def table_one(results: Mapping[str, Any]) -> str:
    settings = results["settings"]
    threshold = settings.get("threshold", LEGACY_THRESHOLD)
    joint = [entry["label"] for entry in full_runs(results) if decision_mode(entry) == "joint"]
    grounded = "every reference grounded at its argmax" + (
        f", the {'rows' if len(joint) > 1 else 'row'} of joint inference jointly (docs/policy.md)" if joint else ""
    )
    protocol = (
        f"the paper's protocol (always placed; {grounded})"
        if threshold == 0
        else f"a scene refused (a failure) when a reference's best token has P < {threshold:g}"
    )
    table = level_table(results, "success", f"Table I: success rate of the mode (%), {protocol}")
    if "unseen_inst" in settings["subsets"] and settings.get("parser") == "offline":
        table += f"\n\n{UNSEEN_INST_NOTE}"
    return table


def _interval(cell: Sequence[float] | None) -> str:
    return MISSING if cell is None else f"{percent(cell[1], 1)}–{percent(cell[2], 1)}"


def _derived(results: Mapping[str, Any]) -> dict[str, Any] | ResultsError:
    try:
        return derived(results)
    except ResultsError as error:
        return error


def interval_table(results: Mapping[str, Any], found: dict[str, Any] | ResultsError | None = None) -> str:
    """Table I's 95% intervals (eval/intervals.py: scenes and seeds), cell by cell; `found`: `derived(results)`
    when the caller has it."""
    found = _derived(results) if found is None else found
    if isinstance(found, ResultsError):
        return f"**95% intervals**: not available ({found})"
    intervals = found["intervals"]
    subsets = _subsets(results)
    lines = [
        "**95% intervals of Table I** (two-level bootstrap over scenes and runs, never narrower than the "
        "Wilson interval of the scenes)",
        "",
        _row(["", *[subset_title(s) if i == 0 else "" for s in subsets for i in range(len(COLUMNS))]]),
        _row(["---", *["---:"] * (len(subsets) * len(COLUMNS))]),
        _row(["**Method**", *[f"**{LEVEL_TITLES[c]}**" for _ in subsets for c in COLUMNS]]),
    ]
    for entry in full_runs(results):
        row = intervals.get(entry["key"], {})
        lines.append(_row([entry["label"], *[_interval(row.get(s, {}).get(c)) for s in subsets for c in COLUMNS]]))
    return "\n".join(lines)


def _selective(cell: Mapping[str, Any]) -> str:
    return f"{percent(cell['coverage'], 1)} / {percent(cell['success_when_placed'], 1)}"


def selective_table(results: Mapping[str, Any], found: dict[str, Any] | ResultsError | None = None) -> str:
    """The robot's refusal gate at its threshold: coverage and success when placed, per subset."""
    found = _derived(results) if found is None else found
    if isinstance(found, ResultsError):
        return f"**Selective placement**: not available ({found})"
    rows = [(entry, found["selective"].get(entry["key"], {})) for entry in full_runs(results)]
    rows = [(entry, row) for entry, row in rows if row]
    if not rows:
        return ""
    subsets = _subsets(results)
    lines = [
        f"**Selective placement with the robot's gate** (a scene is refused when a reference's best token has "
        f"P < {found['gate_threshold']:g}): coverage / success when placed (%)",
        "",
        _row(["Method", *[subset_title(s) for s in subsets]]),
        _row(["---", *["---:"] * len(subsets)]),
    ]
    for entry, row in rows:
        cells = [_selective(row[s]) if s in row else MISSING for s in subsets]
        lines.append(_row([entry["label"], *cells]))
    return "\n".join(lines)


def _difference(cell: Sequence[float] | None) -> str:
    """`+4.67 [+0.9, +9.2]` in points; bold when the interval excludes 0 (the rows differ)."""
    if cell is None:
        return MISSING
    mean, low, high = (100 * value for value in cell[:3])
    text = f"{mean:+.2f} [{low:+.1f}, {high:+.1f}]"
    return f"**{text}**" if low > 0 or high < 0 else text


def paired_table(results: Mapping[str, Any], found: dict[str, Any] | ResultsError | None = None) -> str:
    """Each row's success minus Ours' on the same scenes and runs (Overall, points), with its paired 95% interval."""
    found = _derived(results) if found is None else found
    if isinstance(found, ResultsError):
        return f"**Paired differences**: not available ({found})"
    paired = found.get("paired") or {}
    rows = [(entry, paired[entry["key"]]) for entry in full_runs(results) if paired.get(entry["key"])]
    if not rows:
        return ""
    subsets = _subsets(results)
    lines = [
        "**Differences from Ours on the same scenes and runs** (Overall, points; paired 95% interval, a bootstrap "
        "over scenes and runs, or backbones when there are several; bold: the interval excludes 0, the rows differ)",
        "",
        _row(["Method", *[subset_title(s) for s in subsets]]),
        _row(["---", *["---:"] * len(subsets)]),
    ]
    for entry, row in rows:
        lines.append(_row([entry["label"], *[_difference(row.get(s, {}).get("overall")) for s in subsets]]))
    return "\n".join(lines)


def subset_table(results: Mapping[str, Any], title: str, columns: Mapping[str, Callable[[dict[str, Any]], str]]) -> str:
    """Rows = methods; per subset the named columns, each computed from the subset's overall aggregate."""
    subsets = _subsets(results)
    lines = [
        f"**{title}**",
        "",
        _row(["", *[subset_title(s) if i == 0 else "" for s in subsets for i in range(len(columns))]]),
        _row(["---", *["---:"] * (len(subsets) * len(columns))]),
        _row(["**Method**", *[f"**{name}**" for _ in subsets for name in columns]]),
    ]
    for entry in full_runs(results):
        cells = [entry["label"]]
        for subset in subsets:
            overall = entry["subsets"].get(subset, {}).get("aggregate", {}).get("overall")
            cells += [cell(overall) if overall else MISSING for cell in columns.values()]
        lines.append(_row(cells))
    return "\n".join(lines)


def _physical(overall: dict[str, Any]) -> str:
    if not overall["physical_scenes"]:
        return MISSING
    checked = overall["physical_scenes"]
    return f"{percent(overall['physical_success'], 1)} ({round(overall['physical_success'] * checked)}/{checked})"


def physical_table(results: Mapping[str, Any]) -> str:
    return subset_table(
        results,
        "Physical success (%, successes/scenes checked: the first K scenes of a subset), "
        "beside the success of the mode on the same scenes",
        {
            "Physical": _physical,
            "Mode": lambda o: percent(o["physical_mode_success"], 1),
        },
    )


def diagnosis_table(results: Mapping[str, Any]) -> str:
    return subset_table(
        results,
        "Parse, grounding and program accuracy (%, per scene)",
        {
            "Parse": lambda o: percent(o["parse_accuracy"], 1),
            "Grounding": lambda o: percent(o["grounding_accuracy"], 1),
            "Program": lambda o: percent(o["program_accuracy"], 1),
        },
    )


def stage_table(results: Mapping[str, Any]) -> str:
    """Unsuccessful scenes by the stage they went wrong at, per method and subset."""
    lines = [
        "**Unsuccessful scenes by stage** (failure: the method gave no placement or raised; parse: "
        "wrong tuples; grounding: right tuples, wrong objects; sampling: right problem, placement "
        "misses; placement: the method reports no parse or grounding)",
        "",
        _row(["Method", "Subset", "Scenes", "Unsuccessful", *STAGES]),
        _row(["---", "---", *["---:"] * (2 + len(STAGES))]),
    ]
    for entry in full_runs(results):
        for subset in _subsets(results):
            overall = entry["subsets"].get(subset, {}).get("aggregate", {}).get("overall")
            if overall is None:
                continue
            lines.append(
                _row(
                    [
                        entry["label"],
                        subset_title(subset),
                        str(overall["scenes"]),
                        str(sum(overall["stages"].values())),
                        *[str(overall["stages"][stage]) for stage in STAGES],
                    ]
                )
            )
    return "\n".join(lines)


def failure_list(results: Mapping[str, Any], limit: int = MAX_LISTED_FAILURES) -> str:
    """Scenes where a method gave no placement, with its message (the first `limit` per method)."""
    lines = ["**Method failures**", ""]
    for entry in results["evaluations"]:
        failed = [
            (subset, scene)
            for subset, body in entry["subsets"].items()
            for scene in body["scenes"]
            if scene["failure"] is not None
        ]
        counted = sum(body.get("failed_scenes", 0) for body in entry["subsets"].values())  # a summary's
        if counted:
            label = markdown_text(entry["label"])
            lines.append(f"- {label} ({entry['key']}): {counted} scenes (listed in the full results JSON)")
        if not failed:
            continue
        lines.append(f"- {markdown_text(entry['label'])} ({entry['key']}): {len(failed)} scenes")
        lines += [f"  - `{scene['id']}`: {scene['failure']}" for _, scene in failed[:limit]]
        if len(failed) > limit:
            lines.append(f"  - ... and {len(failed) - limit} more (see the JSON)")
    return "\n".join(lines if len(lines) > 2 else [*lines, "none"])


def unseen_mean(entry: Mapping[str, Any]) -> float | None:
    """The 1:1 mean of the unseen_obj and unseen_inst overall success (the paper's Fig. 7 'unseen')."""
    values = [
        entry["subsets"].get(s, {}).get("aggregate", {}).get("overall", {}).get("success")
        for s in PAPER_SUBSETS
        if s != "seen"
    ]
    return None if None in values else sum(values) / 2


def efficiency_table(results: Mapping[str, Any]) -> str:
    """Overall success on seen and unseen per method and training fraction (empty without fractions)."""
    fractions = sorted({e["fraction"] for e in base_runs(results)})
    if fractions == [1.0]:
        return ""
    lines = [
        "**Sample efficiency: overall success of the mode (%) by share of the training set**",
        "",
        _row(["Method", "Fraction", "Seen", "Unseen (mean of obj and inst)"]),
        _row(["---", "---:", "---:", "---:"]),
    ]
    for entry in sorted(base_runs(results), key=lambda e: (e["method"], e["fraction"])):
        seen = entry["subsets"].get("seen", {}).get("aggregate", {}).get("overall", {}).get("success")
        lines.append(_row([entry["label"], f"{entry['fraction']:g}", percent(seen), percent(unseen_mean(entry))]))
    return "\n".join(lines)


def _code_version(environment: Mapping[str, Any]) -> str:
    """The commit that wrote the results, else (an installed wheel, no git) the package version."""
    commit = (environment.get("git") or {}).get("commit")
    return commit[:12] if commit else str(environment.get("ocplace") or "version unknown")


def failure_counts(results: Mapping[str, Any]) -> str:
    """One line: the scenes without a placement, by reason (the exception's name) over every row; the scenes
    themselves are in `failure_list` (results.md)."""
    import collections

    reasons = collections.Counter(
        scene["failure"].partition(":")[0][:60]  # the exception's name
        for entry in results["evaluations"]
        for body in entry["subsets"].values()
        for scene in body["scenes"]
        if scene["failure"] is not None
    )
    if not reasons:
        return "Every scene of every row was placed."
    counted = ", ".join(f"{reason} {count}" for reason, count in reasons.most_common())
    return f"Scenes without a placement, by reason, over every row: {counted} (each scene in the .md)."


def terminal_summary(results: Mapping[str, Any]) -> str:
    """What a command prints when it has scored: the header, Table I, the paired differences and one line of
    failures; every other table is in the markdown file beside the results."""
    found = _derived(results)
    parts = [_header(results), table_one(results), paired_table(results, found), failure_counts(results)]
    return "\n\n".join(part for part in parts if part)


def _header(results: Mapping[str, Any]) -> str:
    settings = results["settings"]
    return (
        f"Dataset {results['dataset']['dataset_hash']} ({results['dataset']['dir']}){_catalogue_note(results)}, "
        f"backbone `{settings['backbone']}`, parser `{settings['parser']}`, {settings['num_samples']} samples, "
        f"seed {settings['seed']}; ocplace {_code_version(results['environment'])}."
    )


def _catalogue_note(results: Mapping[str, Any]) -> str:
    """Which user catalogue (by content hash) a dataset of your own objects was made from; '' for the benchmark's."""
    config = results["dataset"].get("config") or {}
    catalogue = config.get("catalogue") if isinstance(config, Mapping) else None
    if not isinstance(catalogue, Mapping):
        return ""
    distractors = config.get("distractors")
    mixed = f", with the benchmark's {distractors} objects as distractors" if distractors else ""
    return (
        f", of your catalogue `{markdown_text(catalogue.get('name'))}` (content "
        f"{str(catalogue.get('content_hash'))[:16]}){mixed}"
    )


def render(results: Mapping[str, Any]) -> str:
    """Every table of a results JSON as one markdown document."""
    found = _derived(results)  # the bootstrap once for every table that needs it
    parts = [
        _header(results),
        table_one(results),
        interval_table(results, found),
        paired_table(results, found),
        selective_table(results, found),
        level_table(results, "sample_success", "Mean success over samples (%)"),
        physical_table(results),
        diagnosis_table(results),
        stage_table(results),
        efficiency_table(results),
        failure_list(results),
    ]
    return "\n\n".join(part for part in parts if part) + "\n"


def write_outputs(results: dict[str, Any], out: Path) -> str:
    """Writes RESULTS.json and RESULTS.md (the tables) beside it; returns the markdown."""
    write_results(out, results)
    markdown = render(results)
    write_text_atomic(out.with_suffix(".md"), markdown)
    return markdown
