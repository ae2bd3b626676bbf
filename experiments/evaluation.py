"""Registered methods scored as executor tasks (`ocplace evaluate`), and reruns of a results file.

Each task loads its method (`ocplace.methods`) in the worker and scores it with the harness
(`ocplace.eval.harness`), so the harness itself only scores.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import os
import re
import signal
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ocplace import serial
from ocplace.errors import ResultsError
from ocplace.eval.api import Method
from ocplace.eval.harness import EvalSettings, Evaluation, MethodRun, evaluate_in_own_arena, evaluate_run
from ocplace.eval.results import build_results, dataset_identity, settings_of
from ocplace.methods import registry
from ocplace.methods.contract import MethodSpec
from ocplace.methods.registry import load_method, method_run
from ocplace.models.inference_settings import InferenceSettings

log = logging.getLogger(__name__)

if TYPE_CHECKING:
    from ocplace.runtime.executor import Executor
    from ocplace.sim.mujoco_backend import MujocoScenes


def evaluate_in_worker(
    spec: MethodSpec[Any], run: MethodRun, dataset_dir: str | Path, settings: EvalSettings, method: Method | None = None
) -> Evaluation:
    """`run` loaded by `spec` (unless `method` is given) and scored, with its own physical arena."""
    method = method or load_method(spec, run, settings)
    return evaluate_in_own_arena(run, method, dataset_dir, settings)


def evaluation_key(run: MethodRun, description: dict[str, Any], settings: EvalSettings, dataset_hash: str) -> str:
    """Everything that decides an evaluation's outcome, hashed: a stored evaluation with it is reused."""
    from ocplace.eval.results import SCHEMA

    fields = {
        "schema": SCHEMA,
        "key": run.key,
        "run_dir": None if run.run_dir is None else str(run.run_dir),
        "description": description,
        "settings": serial.to_dict(settings),
        "dataset": dataset_hash,
    }
    return hashlib.sha256(json.dumps(fields, sort_keys=True).encode()).hexdigest()[:16]


def stored_evaluation(
    spec: MethodSpec[Any],
    run: MethodRun,
    settings: EvalSettings,
    dataset_dir: str | Path,
    dataset_hash: str,
    store: Path,
) -> tuple[Path, bool, Evaluation]:
    """(its file in `store`, reused, the evaluation): read from `store` when an evaluation with the same
    `evaluation_key` (run, the loaded method's description, settings, dataset) is there, else scored and stored
    (atomically: a kill leaves it whole or absent)."""
    from ocplace.eval.results import evaluation_to_json
    from ocplace.paths import write_text_atomic

    settings = run.settings(settings)
    method = load_method(spec, run, settings)
    key = evaluation_key(run, serial.to_dict(method.describe()), settings, dataset_hash)
    name = re.sub(r"[^\w.@~+-]", "_", run.key)  # a policy's key holds ':' and '/'
    path = store / f"{name}-{key}.json"
    stored = read_stored_evaluation(path, key) if path.exists() else None
    if stored is not None:  # the label is the command's (`--label`), not part of what is scored
        return path, True, dataclasses.replace(stored, label=run.label)
    evaluation = evaluate_in_worker(spec, run, dataset_dir, settings, method)
    document = evaluation_to_json(evaluation)
    stamped = {"key": key, "sha256": _content_sha256(document), "evaluation": document}
    write_text_atomic(path, json.dumps(stamped, indent=1))
    return path, False, evaluation


def _content_sha256(document: Mapping[str, Any]) -> str:
    return hashlib.sha256(json.dumps(document, sort_keys=True).encode()).hexdigest()


def read_stored_evaluation(path: Path, key: str | None = None) -> Evaluation | None:
    """The evaluation a store keeps in `path`, when its content hashes to the sha256 stored with it and it was
    stored under `key` (when given); else None, said in one line: a damaged, edited or older entry is evaluated
    again, never trusted and never fatal."""
    from ocplace.eval.results import evaluation_from_json
    from ocplace.paths import MAX_JSON_BYTES, read_json_bounded

    try:
        stamped = read_json_bounded(path, MAX_JSON_BYTES)
        document = stamped["evaluation"]
        if stamped["sha256"] != _content_sha256(document) or (key is not None and stamped["key"] != key):
            raise ValueError("its content does not match the checksum stored with it")
        return evaluation_from_json(document)
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as error:
        log.warning("the stored evaluation %s cannot be trusted (%s): it is evaluated again", path, error)
        return None


def evaluate_runs(
    specs: Mapping[str, MethodSpec[Any]],
    runs: Sequence[MethodRun],
    dataset_dir: str | Path,
    settings: EvalSettings,
    executor: Executor,
    progress: bool = True,
    store: Path | None = None,
) -> list[Evaluation]:
    """Every run scored as one task of `executor` (on a worker whose JAX is one CPU wide); in `runs` order.
    `specs` holds the spec of each run's method. With a `store` folder, each finished evaluation is kept there
    and one already there is reused (`stored_evaluation`): an interrupted command resumes."""
    from ocplace.runtime import Task, map_tasks

    settings.validate()
    if store is None:
        tasks = [Task(evaluate_in_worker, (specs[run.method], run, dataset_dir, settings), pinned=True) for run in runs]
    else:
        dataset_hash = dataset_identity(dataset_dir)["dataset_hash"]
        arguments = [(specs[run.method], run, settings, dataset_dir, dataset_hash, store) for run in runs]
        tasks = [Task(stored_evaluation, args, pinned=True) for args in arguments]
    evaluations: list[Evaluation | None] = [None] * len(runs)
    for count, (index, outcome) in enumerate(map_tasks(executor, tasks), 1):
        reused, evaluation = (False, outcome) if store is None else outcome[1:]
        evaluations[index] = evaluation
        if progress:
            done = "stored by an earlier, interrupted command" if reused else f"in {evaluation.wall_s:.1f} s"
            print(f"evaluated {runs[index].key} {done}", flush=True)
        _die_after(count)
    return [evaluation for evaluation in evaluations if evaluation is not None]  # all of them: map_tasks ends


DIE_AFTER_EVALUATIONS_ENV = "OCPLACE_TEST_DIE_AFTER_EVALUATIONS"


def _die_after(count: int) -> None:
    """The tests' deterministic kill point: SIGKILL once `count` evaluations are in (the variable unset: never)."""
    if count == int(os.environ.get(DIE_AFTER_EVALUATIONS_ENV, "0")):
        os.kill(os.getpid(), signal.SIGKILL)


def runs_of(results: Mapping[str, Any], specs: Mapping[str, MethodSpec[Any]] | None = None) -> list[MethodRun]:
    """The method runs a results file evaluated, looked up in `specs` (default: the registry)."""
    specs = registry.method_specs() if specs is None else specs
    runs = []
    for entry in results["evaluations"]:
        if entry["method"] not in specs:
            raise ResultsError(
                f"method {entry['method']!r} of the results is not registered here "
                f"(registered: {', '.join(specs) or 'none'})"
            )
        run_dir = None if entry.get("run_dir") is None else Path(entry["run_dir"])
        if run_dir is not None and not run_dir.exists():
            raise ResultsError(
                f"run directory {run_dir} of {entry['key']!r} is gone; train it again with the "
                "same settings (runs are deterministic) or restore it"
                + (
                    ""
                    if run_dir.is_absolute()
                    else " (results written before run directories were stored absolute name them from the "
                    "folder `ocplace reproduce` or `evaluate` ran in: rerun from that folder)"
                )
            )
        run = method_run(
            specs[entry["method"]], run_dir, entry["fraction"], entry.get("seed"), entry.get("backbone_seed")
        )
        inference = entry.get("inference")
        inference = None if inference is None else serial.from_dict(InferenceSettings, inference)
        runs.append(dataclasses.replace(run, backbone=entry.get("backbone"), inference=inference))
    return runs


def rerun(
    results: Mapping[str, Any],
    specs: Mapping[str, MethodSpec[Any]] | None = None,
    arena: MujocoScenes | None = None,
    progress: bool = True,
    command: object = None,
    executor: Executor | None = None,
) -> dict[str, Any]:
    """Evaluates again every run of `results` with its settings, on its dataset; returns the new results.

    With `executor`, each run is a task as in `ocplace evaluate` and `reproduce` (JAX one CPU wide);
    without, the runs are scored in this process with `arena`.
    """
    if results.get("summary"):
        raise ResultsError(
            "these results are a summary without per-scene outcomes; rerun from the full results.json it was made from"
        )
    dataset_dir = Path(results["dataset"]["dir"])
    if not dataset_dir.is_dir():
        raise ResultsError(
            f"the dataset {dataset_dir} these results were scored on is not there, nor at the same place relative "
            "to the results file: move it back, or move the results file and the dataset together"
        )
    identity = dataset_identity(dataset_dir)
    if identity["manifest_hash"] != results["dataset"]["manifest_hash"]:
        raise ResultsError(
            f"the dataset in {dataset_dir} changed since the evaluation (manifest hash "
            f"{identity['manifest_hash'][:16]} != {results['dataset']['manifest_hash'][:16]})"
        )
    specs = registry.method_specs() if specs is None else specs
    settings = settings_of(results)
    runs = runs_of(results, specs)
    if executor is not None:
        fresh = evaluate_runs(specs, runs, dataset_dir, settings, executor, progress)
    else:
        fresh = [
            evaluate_run(run, load_method(specs[run.method], run, settings), dataset_dir, settings, arena, progress)
            for run in runs
        ]
    return build_results(fresh, dataset_dir, settings, command)


def method_runs(
    specs: Sequence[MethodSpec[Any]], runs: Mapping[str, Path], runs_from: Path | None = None
) -> list[MethodRun]:
    """The run of each spec to evaluate: its `--run` directory, else its row's run in a `reproduce` output
    `runs_from`; EvaluationError when a row that places with a trained run has none."""
    from ocplace.errors import EvaluationError
    from ocplace.experiments.layout import run_directory

    unused = set(runs) - {spec.name for spec in specs}
    if unused:
        raise EvaluationError(f"--run given for method(s) not evaluated: {', '.join(sorted(unused))}")
    selected = []
    for spec in specs:
        run_dir = runs.get(spec.name)
        if run_dir is None and runs_from is not None and spec.needs_run:
            run_dir = run_directory(runs_from, spec.trained_as, 1.0)
        if spec.needs_run and run_dir is None:
            raise EvaluationError(
                f"method {spec.name!r} places with a trained run: pass --run {spec.name}=RUN_DIR (a run directory "
                f"from the training of {spec.trained_as}, e.g. `ocplace reproduce` writes them under OUT/runs)"
            )
        if run_dir is not None and not run_dir.exists():
            raise EvaluationError(f"run directory {run_dir} of {spec.name!r} does not exist")
        selected.append(method_run(spec, run_dir))
    return selected
