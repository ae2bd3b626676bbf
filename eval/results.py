"""The results JSON of an evaluation: what was run, on what, by which code, and every scene's outcome.

    {"schema": "ocplace.evaluation/1", "created": ISO time,
     "command": {"argv": [...], "arguments": {parsed options}} from the CLI (any JSON from Python),
     "environment": {ocplace commit and version, python, jax, jaxlib, flax, mujoco, numpy, platform},
     "dataset": {"dir", "dataset_hash", "manifest_hash", "counts", "config"},
     "settings": EvalSettings (backbone spec, experiment, parser, samples, subsets, limit, physical, seed, chunk),
     "evaluations": [{"key", "method", "label", "fraction", "run_dir", "description" (the method's
                      describe(): configs, seeds, checkpoint hashes, backbone fingerprint, parser),
                      "seed" (only for a repeat of `--seeds`: its training and evaluation seed),
                      "backbone_seed", "backbone" (only for a repeat on another pretraining seed's backbone),
                      "wall_s", "subsets": {subset: {"aggregate": {level|overall: rates},
                                                     "scenes": [SceneOutcome, ...]}}}]}

`rerun` evaluates again from such a file and `compare` lists every difference in outcomes;
`summarise` keeps the aggregates and counts of the scenes (`"summary": true`), and the intervals and
selective table derived from the scenes (`"derived"`); `write_outcomes` keeps each scene's outcome in a
small gzipped JSON-lines file, and `with_outcomes` puts them back into a summary.
"""

from __future__ import annotations

import dataclasses
import datetime
import gzip
import hashlib
import json
import os
import platform
import subprocess
from collections.abc import Collection, Mapping, Sequence
from importlib import metadata
from pathlib import Path
from typing import Any

from ocplace import serial
from ocplace.errors import ResultsError
from ocplace.eval.harness import EvalSettings, Evaluation, SceneOutcome, aggregate_subset
from ocplace.eval.statistics import derived
from ocplace.models.inference_settings import InferenceSettings
from ocplace.paths import atomic_path, write_text_atomic
from ocplace.vocabulary import GATE_THRESHOLD

SCHEMA = "ocplace.evaluation/1"
# The refusal threshold every evaluation applied before Table I took the paper's protocol (2026-12-04);
# a results file without `settings.threshold` was scored with it.
LEGACY_THRESHOLD = 0.5
PACKAGES = ("jax", "jaxlib", "flax", "optax", "mujoco", "numpy", "transformers")
# Outcome fields that must agree for a rerun to count as a reproduction (wall times may not).
COMPARED_FIELDS = (
    "level",
    "success",
    "sample_success",
    "mode",
    "num_samples",
    "failure",
    "parsed",
    "grounded",
    "parse_ok",
    "grounding_ok",
    "program_ok",
    "stage",
    "physical",
    "parse_note",
    "confidence",
    "probabilities",
    "token_names",
    "chosen_tokens",
    "true_tokens",
    "true_ranks",
    "decision",
)


# What readers of a results file index (rerun, tables, figures, the notebook), checked when it is read.
_FieldTypes = dict[str, type | tuple[type, ...]]
_DATASET_FIELDS: _FieldTypes = {"dir": str, "dataset_hash": str, "manifest_hash": str}
_ENTRY_FIELDS: _FieldTypes = {"key": str, "method": str, "label": str, "fraction": (int, float), "subsets": dict}
_SUBSET_FIELDS: _FieldTypes = {"aggregate": dict, "scenes": list}


def git_state() -> dict[str, Any]:
    """The commit of the ocplace source tree and whether it had uncommitted changes."""
    import ocplace

    source = Path(ocplace.__file__).resolve().parent.parent

    def git(*args: str) -> str:
        try:
            return subprocess.run(["git", *args], cwd=source, capture_output=True, text=True, timeout=10).stdout.strip()
        except (OSError, subprocess.SubprocessError):
            return ""

    commit = git("rev-parse", "HEAD")
    return {
        "commit": commit or None,
        "dirty": bool(git("status", "--porcelain", "--untracked-files=no")) if commit else None,
    }


def cpu_model() -> str | None:
    """The processor's model name: results may differ in their last bits between CPU types."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.partition(":")[2].strip()
    except OSError:
        pass
    return platform.processor() or None


def environment() -> dict[str, Any]:
    import ocplace

    versions: dict[str, str | None] = {}
    for package in PACKAGES:
        try:
            versions[package] = metadata.version(package)
        except metadata.PackageNotFoundError:
            versions[package] = None
    return {
        "ocplace": ocplace.__version__,
        "git": git_state(),
        "python": platform.python_version(),
        "platform": platform.platform(),
        "cpu": {"model": cpu_model(), "count": os.cpu_count()},
        "packages": versions,
    }


def dataset_identity(dataset_dir: str | Path) -> dict[str, Any]:
    """Where the dataset is and hashes that change whenever any of its files does."""
    from ocplace.sim.dataset.job import read_manifest

    dataset_dir = Path(dataset_dir)
    manifest = read_manifest(dataset_dir)
    files_digest = hashlib.sha256(json.dumps(manifest["files"], sort_keys=True).encode()).hexdigest()
    return {
        "dir": str(dataset_dir.resolve()),
        "dataset_hash": files_digest[:16],
        "manifest_hash": files_digest,
        "counts": manifest.get("counts"),
        "config": manifest.get("config"),
    }


def evaluation_to_json(evaluation: Evaluation) -> dict[str, Any]:
    return {
        "key": evaluation.key,
        "method": evaluation.method,
        "label": evaluation.label,
        "fraction": evaluation.fraction,
        "run_dir": evaluation.run_dir,
        "description": evaluation.description,
        "wall_s": round(evaluation.wall_s, 3),
        "subsets": {
            subset: {"aggregate": aggregate_subset(outcomes), "scenes": [serial.to_dict(o) for o in outcomes]}
            for subset, outcomes in evaluation.subsets.items()
        },
    } | {
        name: value
        for name, value in (
            ("seed", evaluation.seed),
            ("backbone_seed", evaluation.backbone_seed),
            ("backbone", evaluation.backbone),
            ("inference", None if evaluation.inference is None else serial.to_dict(evaluation.inference)),
        )
        if value is not None
    }


def evaluation_from_json(entry: dict[str, Any]) -> Evaluation:
    return Evaluation(
        key=entry["key"],
        method=entry["method"],
        label=entry["label"],
        fraction=entry["fraction"],
        run_dir=entry["run_dir"],
        description=entry["description"],
        wall_s=entry["wall_s"],
        subsets={
            subset: tuple(serial.from_dict(SceneOutcome, s) for s in body["scenes"])
            for subset, body in entry["subsets"].items()
        },
        seed=entry.get("seed"),
        backbone_seed=entry.get("backbone_seed"),
        backbone=entry.get("backbone"),
        inference=None if entry.get("inference") is None else serial.from_dict(InferenceSettings, entry["inference"]),
    )


def build_results(
    evaluations: Sequence[Evaluation],
    dataset_dir: str | Path,
    settings: EvalSettings,
    command: object = None,
) -> dict[str, Any]:
    """The results file's content. Its paths (the dataset, each run directory) are absolute, so that
    `ocplace evaluate --rerun` finds them from any folder."""
    return {
        "schema": SCHEMA,
        "created": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "command": serial.to_dict(command),
        "environment": environment(),
        "dataset": dataset_identity(dataset_dir),
        "settings": serial.to_dict(settings),
        "gate_threshold": GATE_THRESHOLD,  # the selective table's (eval/statistics.py)
        "evaluations": [evaluation_to_json(_with_absolute_run_dir(e)) for e in evaluations],
    }


def _with_absolute_run_dir(evaluation: Evaluation) -> Evaluation:
    if evaluation.run_dir is None:
        return evaluation
    return dataclasses.replace(evaluation, run_dir=str(Path(evaluation.run_dir).resolve()))


def summarise(results: Mapping[str, Any]) -> dict[str, Any]:
    """The results without per-scene outcomes, small enough to keep beside the tables: every table of
    `eval.table.render` comes out the same, except that failures are counted, not listed."""

    def counts_only(body: Mapping[str, Any]) -> dict[str, Any]:
        return {
            "aggregate": body["aggregate"],
            "scenes": [],
            "omitted_scenes": len(body["scenes"]),
            "failed_scenes": sum(scene["failure"] is not None for scene in body["scenes"]),
        }

    evaluations = [
        {**entry, "subsets": {subset: counts_only(body) for subset, body in entry["subsets"].items()}}
        for entry in results["evaluations"]
    ]
    return {**results, "summary": True, "derived": derived(results), "evaluations": evaluations}


# What each line of an outcomes file holds: the evaluation it belongs to, then the scene's outcome fields.
OUTCOME_ENTRY_FIELDS = ("key", "method", "fraction", "seed", "backbone_seed")
OUTCOME_FIELDS = (
    "id",
    "level",
    "success",
    "sample_success",
    "confidence",
    "stage",
    "failure",
    "parse_ok",
    "grounding_ok",
    "grounded",
    "mode",
    "decision",
    "probabilities",
    "token_names",
    "chosen_tokens",
    "true_tokens",
    "true_ranks",
)


def write_outcomes(path: str | Path, results: Mapping[str, Any], fractions: Collection[float] | None = None) -> Path:
    """Every scene's outcome of `results` as gzipped JSON lines (the fields of `OUTCOME_FIELDS`, a failure by its
    error type), small enough to keep beside a summary: `with_outcomes` puts them back, and the intervals are
    computed from them. The bytes depend on the outcomes only (no time stamp in the gzip header). `fractions`:
    only the evaluations of these training fractions (Table I's: 1.0)."""
    lines = []
    for entry in results["evaluations"]:
        if fractions is not None and entry["fraction"] not in fractions:
            continue
        head = {name: entry.get(name) for name in OUTCOME_ENTRY_FIELDS}
        for subset, body in entry["subsets"].items():
            lines += [
                json.dumps(head | {"subset": subset} | {name: _kept(scene, name) for name in OUTCOME_FIELDS})
                for scene in body["scenes"]
            ]
    data = gzip.compress(("\n".join(lines) + "\n").encode(), mtime=0)
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return path


def _kept(scene: Mapping[str, Any], name: str) -> Any:
    """A scene's field as the outcomes file keeps it: a failure by its error type (the message is in the full
    results), every other field as it is."""
    value = scene.get(name)
    return value.partition(":")[0] if name == "failure" and value is not None else value


def outcome_lines(path: str | Path) -> list[dict[str, Any]]:
    """The lines of an outcomes file (`write_outcomes`): each the evaluation's key fields, its subset and a scene's
    outcome."""
    try:
        text = gzip.decompress(Path(path).read_bytes()).decode()
        return [json.loads(line) for line in text.splitlines() if line.strip()]
    except (OSError, ValueError, EOFError) as error:
        raise ResultsError(f"{path} is missing or not an outcomes file ({error})") from None


def with_outcomes(summary: Mapping[str, Any], path: str | Path) -> dict[str, Any]:
    """A summary (`summarise`) with each scene's outcome read back from its outcomes file (`write_outcomes`)."""
    lines = outcome_lines(path)
    scenes: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for line in lines:
        scenes.setdefault((line["key"], line["subset"]), []).append({name: line.get(name) for name in OUTCOME_FIELDS})
    evaluations, partial = [], False
    for entry in summary["evaluations"]:
        subsets = {}
        for subset, body in entry["subsets"].items():
            found = scenes.get((entry["key"], subset))
            if found is None:  # a file of some evaluations only (Table I's rows, say): this one stays summarised
                subsets[subset], partial = body, True
            elif len(found) != body["aggregate"]["overall"]["scenes"]:
                raise ResultsError(f"{path} holds {len(found)} scenes of {entry['key']} on {subset}, not its results'")
            else:
                subsets[subset] = {"aggregate": body["aggregate"], "scenes": found}
        evaluations.append({**entry, "subsets": subsets})
    restored = {key: value for key, value in summary.items() if key not in ("summary", "derived")}
    return restored | {"evaluations": evaluations} | ({"summary": True} if partial else {})


def write_results(path: str | Path, results: dict[str, Any]) -> Path:
    """Writes the JSON atomically (a kill never leaves half a file), each path also relative to the file's folder
    (`portable`)."""
    path = Path(path)
    write_text_atomic(path, json.dumps(portable(results, path.parent), indent=1) + "\n")
    return path


def portable(results: dict[str, Any], folder: Path) -> dict[str, Any]:
    """`results` with the dataset folder and each run directory also written relative to `folder` (`dir_relative`,
    `run_dir_relative`) beside their absolute form, so that a results file moved or copied together with the
    folders it names still finds them (`anchored`)."""

    def relative(path: str | None) -> str | None:
        return None if path is None else os.path.relpath(Path(path).resolve(), folder.resolve())

    dataset = results.get("dataset")
    if not isinstance(dataset, dict) or not isinstance(dataset.get("dir"), str):
        return results
    evaluations = [
        entry | {"run_dir_relative": relative(entry["run_dir"])} if isinstance(entry.get("run_dir"), str) else entry
        for entry in results.get("evaluations", [])
    ]
    return results | {"dataset": dataset | {"dir_relative": relative(dataset["dir"])}, "evaluations": evaluations}


def anchored(results: dict[str, Any], folder: Path) -> dict[str, Any]:
    """`results` with each path that is gone replaced by its relative form resolved from `folder`, where that exists
    (the absolute form wins while it exists; files written before relative forms were kept are read as written)."""

    def found(absolute: str | None, relative: str | None) -> str | None:
        if absolute is None or not isinstance(relative, str) or Path(absolute).exists():
            return absolute
        moved = (folder / relative).resolve()
        return str(moved) if moved.exists() else absolute

    dataset = results["dataset"]
    evaluations = [
        entry | {"run_dir": found(entry.get("run_dir"), entry.get("run_dir_relative"))}
        for entry in results["evaluations"]
    ]
    return results | {
        "dataset": dataset | {"dir": found(dataset["dir"], dataset.get("dir_relative"))},
        "evaluations": evaluations,
    }


def read_results(path: str | Path) -> dict[str, Any]:
    from ocplace.paths import MAX_JSON_BYTES, read_json_bounded

    path = Path(path)
    try:
        results = read_json_bounded(path, MAX_JSON_BYTES)
    except (OSError, ValueError) as error:  # FileRefused (a FIFO, too large or deep) is a ValueError
        raise ResultsError(f"{path} is missing or not JSON ({error}); write it with `ocplace evaluate`") from None
    if not isinstance(results, dict) or results.get("schema") != SCHEMA:
        raise ResultsError(
            f"{path} is not an ocplace evaluation ({SCHEMA}); it says "
            f"{results.get('schema') if isinstance(results, dict) else type(results).__name__}"
        )
    _check_sections(path, results)
    _check_paths(path, results)
    return anchored(results, path.parent)


def _check_paths(path: Path, results: dict[str, Any]) -> None:
    """ResultsError naming each folder the results name that can name no folder here (a NUL byte, too long)."""
    from ocplace.paths import path_problem

    named = [
        ("dataset.dir", results["dataset"].get("dir")),
        ("dataset.dir_relative", results["dataset"].get("dir_relative")),
    ]
    for k, entry in enumerate(results["evaluations"]):
        named += [(f"evaluations[{k}].{key}", entry.get(key)) for key in ("run_dir", "run_dir_relative")]
    problems = [
        f"{where} ({problem})" for where, text in named if isinstance(text, str) and (problem := path_problem(text))
    ]
    if problems:
        raise ResultsError(
            f"{path} names folders that cannot exist: {'; '.join(problems)}; it was edited or damaged: write it again "
            "with `ocplace evaluate`"
        )


def _has(value: object, fields: Mapping[str, type | tuple[type, ...]]) -> bool:
    """Whether `value` is a dict whose `fields` hold values of their types."""
    return isinstance(value, dict) and all(isinstance(value.get(name), kind) for name, kind in fields.items())


def _is_entry(entry: object) -> bool:
    return (
        isinstance(entry, dict)
        and _has(entry, _ENTRY_FIELDS)
        and isinstance(entry.get("run_dir"), (str, type(None)))
        and all(
            _has(body, _SUBSET_FIELDS) and all(_has(scene, {"id": str}) for scene in body["scenes"])
            for body in entry["subsets"].values()
        )
    )


def _check_sections(path: Path, results: dict[str, Any]) -> None:
    """Refuses a results file cut short or edited by hand, before anything reads or draws from it."""
    bad = [] if _has(results.get("dataset"), _DATASET_FIELDS) else ["dataset"]
    settings = results.get("settings")
    subsets = settings.get("subsets") if isinstance(settings, dict) else None
    if not isinstance(subsets, list) or not all(isinstance(s, str) for s in subsets):
        bad.append("settings")
    entries = results.get("evaluations")
    if not isinstance(entries, list):
        bad.append("evaluations")
        entries = []
    bad += [f"evaluations[{i}]" for i, entry in enumerate(entries) if not _is_entry(entry)]
    if bad:
        raise ResultsError(
            f"{path} is not a complete evaluation: {', '.join(bad[:5])} missing or malformed; "
            "write it again with `ocplace evaluate` or `ocplace reproduce`"
        )


def evaluations(results: Mapping[str, Any]) -> list[Evaluation]:
    return [evaluation_from_json(entry) for entry in results["evaluations"]]


def settings_of(results: Mapping[str, Any]) -> EvalSettings:
    try:
        fields = results["settings"]
        # Results written before the field's rename name the experiment `scale`; before the paper's protocol,
        # every method refused below the gate of then (`LEGACY_THRESHOLD`).
        renamed = {"experiment": fields["scale"]} if "scale" in fields else {}
        gated = {} if "threshold" in fields else {"threshold": LEGACY_THRESHOLD}
        return serial.from_dict(EvalSettings, fields | renamed | gated)
    except (TypeError, ValueError) as error:
        raise ResultsError(
            f"the results' settings are not those of this ocplace's evaluations ({error}); write them again with "
            "`ocplace evaluate` or `ocplace reproduce`"
        ) from None


# ----------------------------------------------------------------------------- comparing two results


def _by_content(description: object) -> object:
    """`description` without the names of what it also identifies by content: a `path` beside its `sha256` (w/o
    LLM's `weights_sha256`), a backbone `spec` beside its `fingerprint` (a run named relative in one command and
    absolute in the other is the same run)."""
    if isinstance(description, Mapping):
        named = {"path": ("sha256", "weights_sha256"), "spec": ("fingerprint",)}
        return {
            key: _by_content(value)
            for key, value in description.items()
            if not (key in named and any(content in description for content in named[key]))
        }
    if isinstance(description, list):
        return [_by_content(value) for value in description]
    return description


def compare(expected: Mapping[str, Any], actual: Mapping[str, Any]) -> list[str]:
    """Every difference that matters between two results: dataset, settings, methods and outcomes."""
    differences = []
    for part in ("dataset_hash", "manifest_hash"):
        if expected["dataset"][part] != actual["dataset"][part]:
            differences.append(f"dataset {part}: {expected['dataset'][part]} != {actual['dataset'][part]}")
    if expected["settings"] != actual["settings"]:
        differences.append(f"settings: {expected['settings']} != {actual['settings']}")
    old = {e["key"]: e for e in expected["evaluations"]}
    new = {e["key"]: e for e in actual["evaluations"]}
    for key in sorted(old.keys() ^ new.keys()):
        differences.append(f"{key}: evaluated in only one of the results")
    for key in [k for k in old if k in new]:
        if _by_content(old[key]["description"]) != _by_content(new[key]["description"]):
            differences.append(f"{key}: describe() differs (configs, checkpoints or backbone)")
        for subset in sorted(old[key]["subsets"].keys() | new[key]["subsets"].keys()):
            differences += _compare_scenes(
                key,
                subset,
                old[key]["subsets"].get(subset, {}).get("scenes", []),
                new[key]["subsets"].get(subset, {}).get("scenes", []),
            )
    return differences


def _compare_scenes(key: str, subset: str, expected: list[dict[str, Any]], actual: list[dict[str, Any]]) -> list[str]:
    differences = []
    if [s["id"] for s in expected] != [s["id"] for s in actual]:
        return [f"{key}/{subset}: different scenes ({len(expected)} vs {len(actual)})"]
    for old, new in zip(expected, actual):
        for field in COMPARED_FIELDS:
            if field in old and old[field] != new.get(field):  # a field added since `expected` was written is new
                differences.append(f"{key}/{subset}/{old['id']}: {field} {old.get(field)!r} != {new.get(field)!r}")
    return differences
