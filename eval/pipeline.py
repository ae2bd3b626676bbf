"""`ocplace reproduce`: one experiment (`ocplace.configs`: smoke, demo, default) end to end.

    library -> dataset -> offline backbone -> training of every registered method (and data
    fractions) -> evaluation on the test subsets -> results.json, results.md, the paper's figures

Every step skips what is already done: the library, dataset, backbone and training runs cache
themselves, and each evaluation is stored under OUT/evaluations/ keyed by everything that decides
its outcome (settings, dataset, the method's describe()). Outputs are written atomically.

    OUT/dataset/                     unless `dataset` points elsewhere
    OUT/runs/<method>/fraction-<f>/  TrainContext.out_dir of each training run
    OUT/evaluations/<key>-<hash>.json
    OUT/results.json, OUT/results.md, OUT/results.summary.json (no per-scene outcomes)
    OUT/figures/                     Fig. 5, Fig. 6 (with Ours and CLIPort-Place), Fig. 7 (with fractions)
    OUT/placement.png                Ours on the first `seen` test scene (when Ours was trained)
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import time
import traceback
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

from ocplace.eval.api import MethodSpec, TrainContext
from ocplace.eval.experiment import Experiment
from ocplace.eval.harness import EvalSettings, Evaluation, MethodRun

SUMMARY_FILE = "results.summary.json"  # aggregates, no per-scene outcomes: small enough to commit


@dataclasses.dataclass(frozen=True)
class PipelineConfig:
    """An experiment, and how this run of it goes about it (none of which changes its results)."""

    experiment: Experiment
    backbone: str | None = None  # a backbone spec to use instead of pretraining the experiment's recipe
    dataset: Path | None = None  # an existing (or wanted) dataset folder instead of OUT/dataset
    workers: int = 0  # dataset generation processes; 0: every CPU
    progress: bool = True


@dataclasses.dataclass(frozen=True)
class Step:
    name: str
    wall_s: float
    detail: str

    def line(self) -> str:
        return f"[{self.name}] {self.wall_s:7.1f} s  {self.detail}"


@dataclasses.dataclass
class PipelineSummary:
    out: Path
    steps: list[Step] = dataclasses.field(default_factory=list)
    errors: list[dict] = dataclasses.field(default_factory=list)  # {"key", "stage", "message"}
    results_path: Path | None = None
    markdown: str = ""
    figures: list[Path] = dataclasses.field(default_factory=list)
    placement_figure: Path | None = None

    def report(self) -> str:
        lines = [step.line() for step in self.steps]
        lines += [f"ERROR {e['stage']} {e['key']}: {e['message']}" for e in self.errors]
        lines.append(f"total {sum(s.wall_s for s in self.steps):.1f} s; results in {self.results_path}")
        return "\n".join(lines)


class _Timer:
    """Records a step's wall time into the summary and prints its line when the step ends."""

    def __init__(self, summary: PipelineSummary, name: str):
        self.summary, self.name, self.detail = summary, name, ""

    def __enter__(self):
        self.began = time.perf_counter()
        return self

    def __exit__(self, *exc):
        step = Step(self.name, time.perf_counter() - self.began, self.detail if exc[0] is None else "failed")
        self.summary.steps.append(step)
        print(step.line(), flush=True)


# ----------------------------------------------------------------------------- steps


def build_library_step(progress: bool):
    from ocplace.sim.library import build_library
    from ocplace.sim.library import default_config as library_config

    return build_library(library_config(), progress=progress)


def dataset_config(config: PipelineConfig):
    import dataclasses as dc

    from ocplace.sim.dataset.config import make_config

    sizes = config.experiment.dataset
    return dc.replace(make_config(sizes.train_scenes, sizes.test_scenes), seed=sizes.seed)


def dataset_step(config: PipelineConfig, dataset_dir: Path) -> str:
    """Generates (or completes) the dataset unless its manifest already records this configuration."""
    import os

    from ocplace.sim.dataset.generate import describe
    from ocplace.sim.dataset.job import MANIFEST_FILE, generate_dataset, read_manifest

    wanted = dataset_config(config)
    if (dataset_dir / MANIFEST_FILE).exists() and read_manifest(dataset_dir).get("config") == describe(wanted):
        return f"{dataset_dir}: already complete"
    manifest = generate_dataset(
        dataset_dir, wanted, workers=config.workers or os.cpu_count() or 1, progress=config.progress
    )
    return f"{dataset_dir}: {sum(sum(c.values()) for c in manifest['counts'].values())} scenes"


def backbone_step(config: PipelineConfig, library) -> str:
    """The backbone spec: `config.backbone`, or the experiment's offline recipe, pretrained if needed."""
    if config.backbone is not None:
        return config.backbone
    from ocplace.train.pretrain.loop import pretrain

    result = pretrain(config.experiment.backbone, library, progress=config.progress)
    return f"offline:{result.directory}"


def selected_specs(config: PipelineConfig, specs: Mapping[str, MethodSpec]) -> list[MethodSpec]:
    from ocplace.eval.registry import select_specs

    methods = config.experiment.evaluation.methods
    return select_specs("all" if methods is None else ",".join(methods), dict(specs))


def planned_runs(config: PipelineConfig, specs: Sequence[MethodSpec]) -> list[tuple[MethodSpec, float]]:
    """(method, training fraction) pairs: 1.0 for every method, plus the fractions for the sample-efficiency methods."""
    plan = config.experiment.evaluation
    runs = []
    for spec in specs:
        fractions = plan.fractions if spec.name in plan.fraction_methods and spec.train is not None else (1.0,)
        runs += [(spec, fraction) for fraction in sorted(set(fractions) | {1.0})]
    return runs


def run_directory(out: Path, name: str, fraction: float) -> Path:
    return out / "runs" / name / f"fraction-{fraction:.2f}"


def train_step(
    spec: MethodSpec, fraction: float, config: PipelineConfig, dataset_dir: Path, backbone: str, out: Path
) -> tuple[Path | None, bool]:
    """(run directory, reused). A finished training is recorded beside its run directory and not
    repeated: a method's own resume may rewrite its files, which would change checkpoint hashes."""
    from ocplace.eval.harness import jsonable
    from ocplace.paths import write_text_atomic

    if spec.train is None:
        return None, False
    experiment = config.experiment
    context = TrainContext(
        dataset_dir=dataset_dir,
        backbone=backbone,
        out_dir=run_directory(out, spec.name, fraction),
        recipe=experiment.recipes.of(spec.name),
        fraction=fraction,
        seed=experiment.seed,
        experiment=experiment.name,
    )
    record = context.out_dir.with_name(context.out_dir.name + ".done.json")
    wanted = jsonable(dataclasses.asdict(context))
    if record.exists():
        done = json.loads(record.read_text())
        if done["context"] == wanted and Path(done["run_dir"]).exists():
            return Path(done["run_dir"]), True
    run_dir = Path(spec.train(context))
    write_text_atomic(record, json.dumps({"context": wanted, "run_dir": str(run_dir)}, indent=1))
    return run_dir, False


def evaluation_settings(config: PipelineConfig, backbone: str) -> EvalSettings:
    experiment = config.experiment
    return EvalSettings(
        backbone=backbone,
        scale=experiment.name,
        parser=experiment.evaluation.parser,
        num_samples=experiment.evaluation.num_samples,
        subsets=experiment.evaluation.subsets,
        physical_scenes=experiment.dataset.physical_scenes,
        seed=experiment.seed,
    )


def placement_figure_step(run_dir: Path, config: PipelineConfig, dataset_dir: Path, backbone: str, path: Path) -> str:
    """Draws Ours on the first `seen` test scene: what a user looks at first."""
    import jax

    from ocplace.eval.ours import scene_input
    from ocplace.models.policy import PlacementPolicy, load_backbone_spec
    from ocplace.models.policy_figure import save_placement
    from ocplace.sim.dataset.job import scene_dirs
    from ocplace.sim.dataset.records import read_scene

    scene_dir = scene_dirs(dataset_dir, "seen")[0]
    experiment = config.experiment
    policy = PlacementPolicy.from_run(load_backbone_spec(backbone), run_dir, parser=experiment.evaluation.parser)
    placement = save_placement(policy, scene_input(read_scene(scene_dir)), jax.random.key(experiment.seed), path)
    print(placement.summary(), flush=True)
    return f"{path} ({scene_dir.name}, {'placed' if placement.error is None else placement.failure})"


def evaluation_key(run: MethodRun, description: dict, settings: EvalSettings, dataset_hash: str) -> str:
    """Everything that decides an evaluation's outcome, hashed: a stored evaluation with it is reused."""
    from ocplace.eval.results import SCHEMA

    fields = {
        "schema": SCHEMA,
        "key": run.key,
        "run_dir": None if run.run_dir is None else str(run.run_dir),
        "description": description,
        "settings": settings.to_json(),
        "dataset": dataset_hash,
    }
    return hashlib.sha256(json.dumps(fields, sort_keys=True).encode()).hexdigest()[:16]


def evaluate_step(
    run: MethodRun,
    settings: EvalSettings,
    dataset_dir: Path,
    dataset_hash: str,
    out: Path,
    arena_factory: Callable,
    progress: bool,
) -> tuple[Evaluation, bool]:
    """The run's evaluation, from OUT/evaluations/ when an identical one is stored; (evaluation, reused)."""
    from ocplace.eval.harness import evaluate_run, jsonable, load_method
    from ocplace.eval.results import evaluation_from_json, evaluation_to_json
    from ocplace.paths import write_text_atomic

    method = load_method(run, settings)
    key = evaluation_key(run, jsonable(method.describe()), settings, dataset_hash)
    path = out / "evaluations" / f"{run.key}-{key}.json"
    if path.exists():
        return evaluation_from_json(json.loads(path.read_text())), True
    arena = arena_factory() if settings.physical_scenes != 0 and run.fraction == 1.0 else None
    evaluation = evaluate_run(run, dataset_dir, settings, arena, progress, method=method)
    write_text_atomic(path, json.dumps(evaluation_to_json(evaluation), indent=1))
    return evaluation, False


# ----------------------------------------------------------------------------- the pipeline


def run_pipeline(
    config: PipelineConfig,
    out: str | Path | None = None,
    specs: Mapping[str, MethodSpec] | None = None,
    command=None,
    library=None,
    arena=None,
) -> PipelineSummary:
    """Runs (or resumes) every step; a method whose training or evaluation raises is reported, not fatal.

    `specs` defaults to the registry; `library` and `arena` (a compiled MujocoScenes) may be passed in
    to reuse them.
    """
    from ocplace.eval.results import build_results, dataset_identity, summarise, write_outputs, write_results

    out = Path(out or config.experiment.out)
    out.mkdir(parents=True, exist_ok=True)
    summary = PipelineSummary(out)
    if specs is None:
        from ocplace.eval.registry import method_specs

        specs = method_specs()
    chosen = selected_specs(config, specs)
    dataset_dir = Path(config.dataset or out / "dataset")

    with _Timer(summary, "library") as step:
        library = library or build_library_step(config.progress)
        step.detail = library.summary()
    with _Timer(summary, "dataset") as step:
        step.detail = dataset_step(config, dataset_dir)
    with _Timer(summary, "backbone") as step:
        backbone = backbone_step(config, library)
        step.detail = backbone

    runs = []
    for spec, fraction in planned_runs(config, chosen):
        run = MethodRun(spec, None, fraction)
        with _Timer(summary, f"train {run.key}") as step:
            try:
                run_dir, reused = train_step(spec, fraction, config, dataset_dir, backbone, out)
                runs.append(dataclasses.replace(run, run_dir=run_dir))
                step.detail = ("done before: " if reused else "") + str(run_dir or "nothing to train")
            except Exception as error:
                summary.errors.append(_error(run.key, "train", error))
                step.detail = f"FAILED: {type(error).__name__}: {error}"

    settings = evaluation_settings(config, backbone)
    dataset_hash = dataset_identity(dataset_dir)["dataset_hash"]
    evaluations, arena = [], _LazyArena(library, arena)
    try:
        for run in runs:
            with _Timer(summary, f"evaluate {run.key}") as step:
                try:
                    evaluation, reused = evaluate_step(
                        run, settings, dataset_dir, dataset_hash, out, arena.get, config.progress
                    )
                    evaluations.append(evaluation)
                    seen = evaluation.subsets.get("seen")
                    step.detail = ("stored " if reused else "") + (
                        f"seen success {sum(o.success for o in seen) / max(len(seen), 1):.1%}" if seen else ""
                    )
                except Exception as error:
                    summary.errors.append(_error(run.key, "evaluate", error))
                    step.detail = f"FAILED: {type(error).__name__}: {error}"
    finally:
        arena.close()

    with _Timer(summary, "results") as step:
        results = build_results(evaluations, dataset_dir, settings, command)
        results["pipeline"] = {
            "config": _config_json(config),
            "steps": [dataclasses.asdict(s) for s in summary.steps],
            "errors": summary.errors,
        }
        summary.results_path = out / "results.json"
        summary.markdown = write_outputs(results, summary.results_path)
        write_results(out / SUMMARY_FILE, summarise(results))
        step.detail = f"{summary.results_path}, {summary.results_path.with_suffix('.md')}, {out / SUMMARY_FILE}"
    if evaluations:
        with _Timer(summary, "paper figures") as step:
            try:
                from ocplace.eval.figures import write_figures

                summary.figures = write_figures(results, out / "figures", dataset_dir, config.experiment.seed)
                step.detail = ", ".join(str(path) for path in summary.figures)
            except Exception as error:
                summary.errors.append(_error("figures", "figures", error))
                step.detail = f"FAILED: {type(error).__name__}: {error}"
    ours = [run for run in runs if run.spec.name == "ours" and run.fraction == 1.0 and run.run_dir is not None]
    if ours and "seen" in config.experiment.evaluation.subsets:
        with _Timer(summary, "figure") as step:
            try:
                step.detail = placement_figure_step(
                    ours[0].run_dir, config, dataset_dir, backbone, out / "placement.png"
                )
                summary.placement_figure = out / "placement.png"
            except Exception as error:
                summary.errors.append(_error("ours", "figure", error))
                step.detail = f"FAILED: {type(error).__name__}: {error}"
    return summary


class _LazyArena:
    """Compiles the MuJoCo arena on first use only (all evaluations may be stored already)."""

    def __init__(self, library, arena=None):
        self.library, self.arena, self.owned = library, arena, False

    def get(self):
        if self.arena is None:
            from ocplace.sim.mujoco_backend import MujocoScenes

            self.arena, self.owned = MujocoScenes.from_library(self.library), True
        return self.arena

    def close(self):
        if self.owned:
            self.arena.close()


def _error(key: str, stage: str, error: Exception) -> dict:
    print(f"ERROR in step {stage} of {key}:", flush=True)
    traceback.print_exception(error)
    return {"key": key, "stage": stage, "message": f"{type(error).__name__}: {error}"}


def _config_json(config: PipelineConfig) -> dict:
    from ocplace.eval.harness import jsonable

    return jsonable(dataclasses.asdict(config))
