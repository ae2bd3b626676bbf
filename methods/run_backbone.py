"""The backbone a trained run was trained on, found the same way by `export`, `place --adapters` and `evaluate`.

A run's training records the backbone spec it was given (its `.done.json` record, `methods/contract.py`) and the
backbone's fingerprint (`run.json`, and the adapters' weights file). The spec is tried first when it can load here
(an offline backbone's folder that exists, a CLIP checkpoint); else the saved offline backbone with that
fingerprint. The loader checks the fingerprint either way (`models/backbone_match.py` `check_trained_on`).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

from ocplace.errors import BackboneUnavailable, EvaluationError
from ocplace.paths import RUN_FILE


def recorded_backbone(run_dir: str | Path) -> str | None:
    """The backbone spec the training of `run_dir` was given (its `.done.json` record), if recorded."""
    from ocplace.methods.contract import done_record

    try:
        spec = json.loads(done_record(Path(run_dir)).read_text())["context"]["backbone"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return spec if isinstance(spec, str) else None


def recorded_fingerprint(run_dir: str | Path) -> str | None:
    """The fingerprint of the backbone `run_dir` was trained on (its `run.json`), if recorded."""
    try:
        fingerprint = json.loads((Path(run_dir) / RUN_FILE).read_text())["backbone_fingerprint"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return fingerprint if isinstance(fingerprint, str) else None


def trained_backbone(run_dir: str | Path, fingerprint: str | None = None) -> str:
    """The spec of the backbone `run_dir` was trained on (`fingerprint`: the one its weights record, when the
    run folder has no `run.json`); BackboneUnavailable naming it, and how to get it, when it is not here."""
    from ocplace.models.backbone_match import backbone_hint
    from ocplace.models.offline_backbone import saved_backbone_with

    spec = recorded_backbone(run_dir)
    if spec is not None and _loadable_here(spec):
        return spec
    fingerprint = fingerprint or recorded_fingerprint(run_dir)
    directory = saved_backbone_with(fingerprint) if fingerprint else None
    if directory is not None:
        return f"offline:{directory}"
    given = f"`{spec}`, not here" if spec else "no spec recorded"
    if not fingerprint:
        raise BackboneUnavailable(
            f"{run_dir} records no backbone fingerprint to find its backbone by ({given}): pass `--backbone SPEC`, "
            "the spec its training used"
        )
    raise BackboneUnavailable(
        f"{run_dir} was trained on the backbone with fingerprint {fingerprint[:12]} ({given}); "
        f"{backbone_hint(fingerprint)}"
    )


def runs_backbone(run_dirs: Sequence[str | Path]) -> str | None:
    """The one backbone every run in `run_dirs` was trained on (None for no runs); EvaluationError when they differ:
    one evaluation scores every row on one backbone."""
    specs = {str(run_dir): trained_backbone(run_dir) for run_dir in run_dirs}
    if len(set(specs.values())) > 1:
        listed = "; ".join(f"{run} on {spec}" for run, spec in specs.items())
        raise EvaluationError(f"the runs were trained on different backbones ({listed}): evaluate them separately")
    return next(iter(specs.values()), None)


def _loadable_here(spec: str) -> bool:
    from ocplace.models.backbone import looks_like_path

    kind, _, argument = spec.partition(":")
    if kind == "offline":  # a recipe name is the default cache's folder, which may hold another pretraining
        return Path(argument).is_dir()
    return Path(argument).expanduser().is_dir() or not looks_like_path(argument)  # a hub id loads, or says why
