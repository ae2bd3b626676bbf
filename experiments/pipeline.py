"""`ocplace reproduce`: one experiment (`ocplace.configs`: smoke, demo, default) end to end.

    library -> dataset -> offline backbone -> training of every registered method (and data
    fractions, and seeds) -> evaluation on the test subsets -> results.json, results.md, the paper's figures

From the backbone on, the steps are nodes of a task graph (`task_graph`) that the executor runs
side by side where they do not depend on each other (docs/distributed.md).

Every step skips what is already done: the library, dataset, backbone and training runs cache
themselves, and each evaluation is stored under OUT/evaluations/ keyed by everything that decides
its outcome (settings, dataset, the method's describe()). Outputs are written atomically.

    OUT/dataset/                               unless `dataset` points elsewhere
    OUT/runs/<method>/fraction-<f>[-seed-<s>]/ TrainContext.out_dir of each training run (and repeat)
    OUT/evaluations/<key>-<hash>.json
    OUT/results.json, OUT/results.md, OUT/results.summary.json (no per-scene outcomes)
    OUT/figures/                               Fig. 5, Fig. 6 (with Ours and CLIPort-Place), Fig. 7 (with fractions)
    OUT/placement.png                          Ours on the first `seen` test scene (when Ours was trained)
"""

from __future__ import annotations

import dataclasses
import functools
import time
import traceback
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ocplace import serial
from ocplace.errors import ConfigError, ResultsError
from ocplace.eval.harness import EvalSettings, Evaluation, MethodRun
from ocplace.experiments.experiment import Experiment
from ocplace.experiments.layout import run_directory
from ocplace.methods.contract import MethodSpec, TrainContext, train_once
from ocplace.methods.registry import method_run, method_specs, select_specs
from ocplace.runtime import Executor, ExecutorConfig, Task, open_executor
from ocplace.runtime.graph import Node, Outcome, run_graph

if TYPE_CHECKING:
    from ocplace.models.offline_recipes import PretrainConfig
    from ocplace.sim.dataset.config import DatasetConfig
    from ocplace.sim.library.library import Library

SUMMARY_FILE = "results.summary.json"  # aggregates, no per-scene outcomes: small enough to commit
OUTCOMES_FILE = "results.outcomes.jsonl.gz"  # each scene's outcome, compact: small enough to commit
PLACEMENT_FIGURE = "placement.png"
POLICY_FOLDER = "policy"  # OUT/policy: the drawn Ours run as a policy folder (methods/export.py)
FIGURE_NODE = "figure ours"  # a failure is reported as stage "figure" of "ours"


@dataclasses.dataclass(frozen=True)
class PipelineConfig:
    """An experiment, and how this run of it goes about it (none of which changes its results)."""

    experiment: Experiment
    backbone: str | None = None  # a backbone spec to use instead of pretraining the experiment's recipe
    dataset: Path | None = None  # an existing (or wanted) dataset folder instead of OUT/dataset
    executor: ExecutorConfig = ExecutorConfig()  # where the graph's tasks run (local pool or Ray)
    progress: bool = True
    # Test-only datasets of users' catalogues (`generate --catalogue`), scored with the same runs, each into
    # OUT/<catalogue>.results.json (docs/library.md, "Test on your own objects").
    own_datasets: tuple[Path, ...] = ()

    def __post_init__(self) -> None:
        self.experiment.validate()  # a value that cannot work fails here, not hours into the run


@dataclasses.dataclass(frozen=True)
class Step:
    name: str
    wall_s: float
    detail: str
    cpus: int = 1  # what the step held: its task's declared width, or the pool's workers for library and dataset

    def line(self) -> str:
        return f"[{self.name}] {self.wall_s:7.1f} s  {self.detail}"


@dataclasses.dataclass
class PipelineSummary:
    out: Path
    steps: list[Step] = dataclasses.field(default_factory=list)
    errors: list[dict[str, Any]] = dataclasses.field(default_factory=list)  # {"key", "stage", "message"}
    results_path: Path | None = None
    markdown: str = ""  # every table (results.md)
    terminal: str = ""  # what the command prints at the end: Table I, the paired table, failures by reason
    figures: list[Path] = dataclasses.field(default_factory=list)
    placement_figure: Path | None = None
    wall_s: float = 0.0  # the whole run; steps of the task graph overlap, so their sum is more
    own_results: list[Path] = dataclasses.field(default_factory=list)  # one per `own_datasets`, their subsets scored

    def report(self) -> str:
        """The run's closing lines, after the tables: its errors and its wall (each step's line was printed as the
        step ended, and is in results.json)."""
        lines = [f"ERROR {e['stage']} {e['key']}: {e['message']}" for e in self.errors]
        tables = self.results_path.with_suffix(".md") if self.results_path else None
        lines.append(f"total {self.wall_s:.1f} s wall; results in {self.results_path}, every table in {tables}")
        return "\n".join(lines)


class _Timer:
    """Records a step's wall time into the summary and prints its line when the step ends."""

    def __init__(self, summary: PipelineSummary, name: str, cpus: int = 1):
        self.summary, self.name, self.detail, self.cpus = summary, name, "", cpus

    def __enter__(self) -> _Timer:
        self.began = time.perf_counter()
        return self

    def __exit__(self, *exc: object) -> None:
        detail = self.detail if exc[0] is None else "failed"
        step = Step(self.name, time.perf_counter() - self.began, detail, self.cpus)
        self.summary.steps.append(step)
        print(step.line(), flush=True)


# ----------------------------------------------------------------------------- steps in this process


def build_library_step(executor: Executor, progress: bool) -> Library:
    from ocplace.sim.library import build_library
    from ocplace.sim.library import default_config as library_config

    return build_library(library_config(), progress=progress, executor=executor)


def dataset_config(config: PipelineConfig) -> DatasetConfig:
    from ocplace.sim.dataset.config import make_config

    sizes = config.experiment.dataset
    return dataclasses.replace(make_config(sizes.train_scenes, sizes.test_scenes), seed=sizes.seed)


def dataset_step(config: PipelineConfig, dataset_dir: Path, executor: Executor) -> str:
    """Generates (or completes) the dataset unless its manifest already records this configuration."""
    from ocplace.sim.dataset.generate import describe
    from ocplace.sim.dataset.job import MANIFEST_FILE, generate_dataset, read_manifest

    wanted = dataset_config(config)
    if (dataset_dir / MANIFEST_FILE).exists() and read_manifest(dataset_dir).get("config") == describe(wanted):
        return f"{dataset_dir}: already complete"
    manifest = generate_dataset(dataset_dir, wanted, executor=executor, progress=config.progress)
    return f"{dataset_dir}: {sum(sum(c.values()) for c in manifest['counts'].values())} scenes"


def selected_specs(config: PipelineConfig, specs: Mapping[str, MethodSpec[Any]]) -> list[MethodSpec[Any]]:
    methods = config.experiment.evaluation.methods
    return select_specs("all" if methods is None else ",".join(methods), dict(specs))


def planned_runs(config: PipelineConfig, specs: Sequence[MethodSpec[Any]]) -> list[MethodRun]:
    """Every run to train and evaluate: each method on the whole training set, the sample-efficiency
    methods on every fraction, and each of those again per extra seed (`EvalPlan.seeds`) and, if it uses the
    backbone, on each extra backbone seed (`EvalPlan.backbone_seeds`); only the `EvalPlan.seed_methods` and
    `seed_fractions` when they name some."""
    experiment = config.experiment
    plan, base = experiment.evaluation, experiment.seed
    runs = []
    for spec in specs:
        learns = spec.train is not None
        fractions = plan.fractions if spec.name in plan.fraction_methods and learns else (1.0,)
        repeated = plan.seed_methods is None or spec.name in plan.seed_methods
        for fraction in sorted(set(fractions) | {1.0}):
            again = repeated and (plan.seed_fractions is None or fraction in plan.seed_fractions)
            seeds = [None, *range(base + 1, base + plan.seeds)] if again else [None]
            backbones = [None, *experiment.backbone_seeds()] if again and spec.uses_backbone else [None]
            inference = experiment.inference.get(spec.name)
            runs += [
                method_run(spec, None, fraction, seed, backbone, inference) for backbone in backbones for seed in seeds
            ]
    return runs


def evaluation_settings(config: PipelineConfig, backbone: str) -> EvalSettings:
    experiment = config.experiment
    return EvalSettings(
        backbone=backbone,
        experiment=experiment.name,
        parser=experiment.evaluation.parser,
        num_samples=experiment.evaluation.num_samples,
        subsets=experiment.evaluation.subsets,
        physical_scenes=experiment.dataset.physical_scenes,
        seed=experiment.seed,
    )


def placement_figure_task(run_dir: Path, parser: str, seed: int, dataset_dir: Path, backbone: str, path: Path) -> str:
    """Draws Ours (trained in `run_dir`) on the first `seen` test scene: what a user looks at first; and writes
    that policy as the policy folder `POLICY_FOLDER` beside the figure (OUT/policy)."""
    import jax

    from ocplace.methods.export import export_trained
    from ocplace.methods.policy_method import scene_input
    from ocplace.models.backbone import load_backbone
    from ocplace.models.policy import PlacementPolicy
    from ocplace.models.policy_figure import save_placement
    from ocplace.sim.dataset.job import listed_scenes

    scene = listed_scenes(dataset_dir, "seen")[0]
    policy = PlacementPolicy.from_run(load_backbone(backbone), run_dir, parser=parser)
    placement = save_placement(policy, scene_input(scene.read()), jax.random.key(seed), path)
    print(placement.summary(), flush=True)
    outcome = "placed" if placement.error is None else placement.failure
    folder = export_trained(
        policy, path.parent / POLICY_FOLDER, parser=parser, run_dir=run_dir, backbone=backbone, dataset=dataset_dir
    )
    return f"{path} ({scene.name}, {outcome}); policy folder {folder}"


# ----------------------------------------------------------------------------- tasks of the graph (any worker)


def pretrain_task(recipe: PretrainConfig, progress: bool, cpus: int = 1, share_renders: bool = False) -> str:
    """The offline backbone of `recipe`, pretrained unless cached (rendering in `cpus` processes, into the folder
    its backbone seeds share if `share_renders`); returns its spec."""
    from ocplace.sim.library import load_library
    from ocplace.train.pretrain.loop import pretrain

    backbone = pretrain(recipe, load_library(), progress=progress, render_workers=cpus, share_renders=share_renders)
    return f"offline:{backbone.directory}"


def train_context(
    run: MethodRun, config: PipelineConfig, dataset_dir: Path, backbone: str, out: Path
) -> TrainContext[Any]:
    experiment = config.experiment
    return TrainContext(
        dataset_dir=dataset_dir,
        backbone=backbone,
        out_dir=run_directory(out, run.method, run.fraction, run.seed, run.backbone_seed),
        recipe=experiment.recipe(run.method),
        fraction=run.fraction,
        seed=experiment.seed if run.seed is None else run.seed,
        experiment=experiment.name,
    )


def prepare_task(spec: MethodSpec[Any], context: TrainContext[Any]) -> str:
    assert spec.prepare is not None, "the graph prepares for methods with shared inputs only"
    spec.prepare(context)
    return "shared inputs ready"


def evaluate_task(
    spec: MethodSpec[Any], run: MethodRun, settings: EvalSettings, dataset_dir: Path, dataset_hash: str, out: Path
) -> tuple[Path, bool, str]:
    """(stored evaluation's path, reused, seen success): from OUT/evaluations/ when an identical one is
    stored, else scored now and stored."""
    from ocplace.experiments.evaluation import stored_evaluation

    path, reused, evaluation = stored_evaluation(spec, run, settings, dataset_dir, dataset_hash, out / "evaluations")
    seen = evaluation.subsets.get("seen")
    return path, reused, f"seen success {sum(o.success for o in seen) / max(len(seen), 1):.1%}" if seen else ""


# ----------------------------------------------------------------------------- the graph


def task_graph(
    config: PipelineConfig,
    specs: Mapping[str, MethodSpec[Any]],
    runs: list[MethodRun],
    dataset_dir: Path,
    out: Path,
    dataset_hash: str,
) -> list[Node]:
    """backbone -> each method's shared inputs -> (train method x fraction x seed) -> evaluate each run.

    Every task is pinned to the CPUs it declares (the experiment's `cpus`; an evaluation one), so JAX
    compiles for that many wherever it runs and the results are the same bits on any executor
    (ocplace/runtime/width.py).
    """
    cpus = config.experiment.cpus
    source = backbone_source(config, runs)
    nodes: list[Node] = source.nodes()
    backbone_after, backbone_of = source.after, source.spec

    def method_node(
        key: str,
        function: Callable[[MethodSpec[Any], TrainContext[Any]], object],
        run: MethodRun,
        after: tuple[str, ...],
    ) -> Node:
        """A node running `function(spec, TrainContext)` for `run`, once its backbone is known."""

        def make(done: Mapping[str, Any]) -> Task:
            context = train_context(run, config, dataset_dir, backbone_of(done, run), out)
            return Task(function, (specs[run.method], context), cpus=cpus.train, pinned=True)

        return Node(key, make, after)

    trainings = list({trained.key: trained for run in runs if (trained := trained_run(run, specs))}.values())
    sharing: dict[
        tuple[object, int | None], list[MethodRun]
    ] = {}  # (prepare function, backbone seed) -> the runs whose trainings need those inputs
    for run in trainings:
        spec = specs[run.method]
        if spec.prepare is not None:
            sharing.setdefault((spec.prepare, run.backbone_seed), []).append(run)
    prepare_key: dict[
        tuple[str, int | None], str
    ] = {}  # (method, backbone seed) -> the key of the node making its shared inputs, once for all
    for (_, backbone_seed), shared in sharing.items():
        names = list(dict.fromkeys(run.method for run in shared))
        key = f"prepare {'+'.join(names)}" + ("" if backbone_seed is None else f" ~backbone{backbone_seed}")
        prepare_key |= {(name, backbone_seed): key for name in names}
        nodes.append(method_node(key, prepare_task, shared[0], backbone_after(shared[0])))
    for run in trainings:
        prepared = prepare_key.get((run.method, run.backbone_seed))
        after = backbone_after(run) + ((prepared,) if prepared else ())
        nodes.append(method_node(f"train {run.key}", train_once, run, after))
    for run in evaluation_order(runs, specs):
        trained = trained_run(run, specs)
        after = backbone_after(run) + ((f"train {trained.key}",) if trained else ())
        evaluate = _evaluate_maker(config, specs[run.method], run, dataset_dir, out, dataset_hash, backbone_of, trained)
        nodes.append(Node(f"evaluate {run.key}", evaluate, after))
    drawn = next((run for run in runs if run.method == "ours" and run.key == "ours"), None)
    if drawn is not None and specs["ours"].train is not None and "seen" in config.experiment.evaluation.subsets:
        draw = _figure_maker(config, dataset_dir, out, backbone_of, drawn)
        nodes.append(Node(FIGURE_NODE, draw, backbone_after(drawn) + (f"train {drawn.key}",)))
    return nodes


@dataclasses.dataclass(frozen=True)
class PretrainedBackbones:
    """Where the runs' backbones come from when none is given: pretrained in the graph, one node per backbone seed
    (the experiment's own first), one after another."""

    config: PipelineConfig
    seeds: tuple[int | None, ...]  # None: the recipe's own optimiser seed

    def nodes(self) -> list[Node]:
        cpus = self.config.experiment.cpus
        nodes: list[Node] = []
        for previous, seed in zip([None, *self.seeds], self.seeds, strict=False):
            recipe = self.config.experiment.backbone_recipe(seed)
            arguments = (recipe, self.config.progress, cpus.pretrain, len(self.seeds) > 1)
            task = Task(pretrain_task, arguments, cpus=cpus.pretrain, pinned=True)
            # One after another: the first that pretrains renders and encodes for the others (a cached one does not),
            # and no two write the shared captions at once.
            waits: tuple[str, ...] = () if seed is None else (backbone_key(previous),)
            nodes.append(Node(backbone_key(seed), functools.partial(_given, task), waits))
        return nodes

    def after(self, run: MethodRun) -> tuple[str, ...]:
        """The nodes `run`'s tasks wait for: its backbone's."""
        return (backbone_key(run.backbone_seed),)

    def spec(self, done: Mapping[str, Any], run: MethodRun) -> str:
        """The backbone spec of `run`, from what its backbone's node returned."""
        spec: str = done[backbone_key(run.backbone_seed)]
        return spec


@dataclasses.dataclass(frozen=True)
class GivenBackbone:
    """Where the runs' backbones come from with `--backbone SPEC`: that spec for every run, no node to wait for."""

    given: str

    def nodes(self) -> list[Node]:
        return []

    def after(self, run: MethodRun) -> tuple[str, ...]:
        return ()

    def spec(self, done: Mapping[str, Any], run: MethodRun) -> str:
        return self.given


def backbone_source(config: PipelineConfig, runs: list[MethodRun]) -> PretrainedBackbones | GivenBackbone:
    """The strategy that gives each run its backbone: the one given, or those the graph pretrains."""
    if config.backbone is not None:
        return GivenBackbone(config.backbone)
    seeds = tuple(dict.fromkeys(run.backbone_seed for run in [MethodRun("", ""), *runs]))  # the base one first
    return PretrainedBackbones(config, seeds)


def trained_run(run: MethodRun, specs: Mapping[str, MethodSpec[Any]]) -> MethodRun | None:
    """The run whose training makes `run`'s run directory: `run` itself for a row that trains, the same run of the row
    it places with for an inference-only row (`MethodSpec.places_with`), None for a row that learns nothing."""
    spec = specs[run.method]
    if spec.places_with is not None:
        owner = specs[spec.places_with]
        return dataclasses.replace(run, method=owner.name, label=owner.label, inference=None)
    return run if spec.train is not None else None


def _given(task: Task, done: Mapping[str, Any]) -> Task:
    return task


def backbone_key(seed: int | None) -> str:
    """The graph node pretraining the experiment's backbone (None) or its repeat with another optimiser seed."""
    return "backbone" if seed is None else f"backbone seed {seed}"


def evaluation_order(runs: list[MethodRun], specs: Mapping[str, MethodSpec[Any]]) -> list[MethodRun]:
    """The order the graph starts evaluations in, when their CPUs free up: the first that encodes the
    backbone's shared test features, then those that encode their own, then those that read the shared ones.

    The encoder then works beside independent work, instead of beside evaluations that wait for its
    features (models/shared_features.py); each evaluation computes the same bits in any order.
    """
    sharing = [run for run in runs if specs[run.method].shares_test_features]
    own = [run for run in runs if not specs[run.method].shares_test_features]
    return sharing[:1] + own + sharing[1:]


def _evaluate_maker(
    config: PipelineConfig,
    spec: MethodSpec[Any],
    run: MethodRun,
    dataset_dir: Path,
    out: Path,
    dataset_hash: str,
    backbone_of: Callable[[Mapping[str, Any], MethodRun], str],
    trained: MethodRun | None,
) -> Callable[[Mapping[str, Any]], Task]:
    def make(done: Mapping[str, Any]) -> Task:
        backbone = backbone_of(done, run)
        ready = run if trained is None else dataclasses.replace(run, run_dir=done[f"train {trained.key}"][0])
        if run.backbone_seed is not None:  # recorded with the evaluation, so a rerun loads this backbone
            ready = dataclasses.replace(ready, backbone=backbone)
        settings = evaluation_settings(config, backbone)
        return Task(evaluate_task, (spec, ready, settings, dataset_dir, dataset_hash, out), pinned=True)

    return make


def _figure_maker(
    config: PipelineConfig,
    dataset_dir: Path,
    out: Path,
    backbone_of: Callable[[Mapping[str, Any], MethodRun], str],
    run: MethodRun,
) -> Callable[[Mapping[str, Any]], Task]:
    def make(done: Mapping[str, Any]) -> Task:
        run_dir = done[f"train {run.key}"][0]
        experiment = config.experiment
        arguments = (run_dir, experiment.evaluation.parser, experiment.seed, dataset_dir, backbone_of(done, run))
        return Task(placement_figure_task, (*arguments, out / PLACEMENT_FIGURE), pinned=True)

    return make


def _node_detail(key: str, value: Any) -> str:
    if key.startswith(("backbone", "prepare ")) or key == FIGURE_NODE:
        return str(value)
    if key.startswith("train "):
        run_dir, reused = value
        return ("done before: " if reused else "") + str(run_dir)
    _, reused, seen = value
    return ("stored " if reused else "") + str(seen)


# ----------------------------------------------------------------------------- the pipeline


def run_pipeline(
    config: PipelineConfig,
    out: str | Path | None = None,
    specs: Mapping[str, MethodSpec[Any]] | None = None,
    command: object = None,
    library: Library | None = None,
) -> PipelineSummary:
    """Runs (or resumes) every step; a method whose training or evaluation raises is reported, not fatal.

    `specs` defaults to the registry; a `library` passed in is not built again (the tasks load it from
    the cache, where it was built).
    """
    from ocplace.paths import check_writable

    specs = method_specs() if specs is None else specs
    out = Path(out or config.experiment.out)
    unknown = config.experiment.evaluation.unknown_methods(specs)
    if config.backbone is not None and config.experiment.evaluation.backbone_seeds > 1:
        unknown.append(
            f"evaluation.backbone_seeds is {config.experiment.evaluation.backbone_seeds}, but a given backbone "
            f"({config.backbone}) has no pretraining to repeat: drop --backbone or set evaluation.backbone_seeds=1"
        )
    for own in config.own_datasets:
        own_dataset_subsets(own)  # checked before any work
    unknown += [
        f"{spec.name} places with {spec.places_with}'s runs, a row not registered (registered: {', '.join(specs)})"
        for spec in specs.values()
        if spec.places_with is not None and spec.places_with not in specs
    ]
    if not unknown:
        unknown = config.experiment.missing_recipes(spec.trained_as for spec in selected_specs(config, specs))
    if unknown:
        raise ConfigError(f"experiment {config.experiment.name!r} cannot run: {'; '.join(unknown)}")
    check_writable(out, as_folder=True)
    check_outputs(config, out)
    with open_executor(config.executor) as executor:
        return _run(config, executor, out, specs, command, library)


def check_outputs(config: PipelineConfig, out: Path) -> None:
    """OutputError, before any work, listing every path of OUT that is taken by the wrong kind (a file where a
    folder goes, a folder where a file goes), every catalogue scored twice into one file, and an OUT on or inside
    its own dataset: each would otherwise fail (or mix files) once the runs are trained."""
    from ocplace.errors import OutputError

    files = ["results.json", "results.md", SUMMARY_FILE, OUTCOMES_FILE, PLACEMENT_FIGURE]
    folders = ["runs", "evaluations", "figures", POLICY_FOLDER, *([] if config.dataset else ["dataset"])]
    names = [own_dataset_subsets(own)[0] for own in config.own_datasets]
    problems = [f"{own} is scored twice into {out / name}.results.json" for own, name in _repeated(names, config)]
    files += [f"{name}.results{suffix}" for name in dict.fromkeys(names) for suffix in (".json", ".md")]
    problems += [f"{out / name} is a folder, where a file goes" for name in files if (out / name).is_dir()]
    problems += [
        f"{out / name} is a file, where a folder goes"
        for name in folders
        if (out / name).exists() and not (out / name).is_dir()
    ]
    if config.dataset is not None and out.resolve().is_relative_to(Path(config.dataset).resolve()):
        problems.append(f"--out {out} is the dataset {config.dataset} or inside it: the runs would mix with scenes")
    if problems:
        raise OutputError(
            f"cannot write the outputs of `reproduce` into {out}: {'; '.join(problems)}; move those aside or "
            "choose another --out"
        )


def _repeated(names: list[str], config: PipelineConfig) -> list[tuple[Path, str]]:
    """The own datasets whose catalogue name an earlier one has, with that name."""
    return [(own, name) for k, (own, name) in enumerate(zip(config.own_datasets, names)) if name in names[:k]]


def _run(
    config: PipelineConfig,
    executor: Executor,
    out: Path,
    specs: Mapping[str, MethodSpec[Any]],
    command: object,
    library: Library | None,
) -> PipelineSummary:
    from ocplace.eval.results import dataset_identity
    from ocplace.models.offline_recipes import output_dir

    began = time.perf_counter()
    out.mkdir(parents=True, exist_ok=True)
    summary = PipelineSummary(out)
    runs = planned_runs(config, selected_specs(config, specs))
    dataset_dir = Path(config.dataset or out / "dataset")
    print(f"running on a {config.executor.describe()}", flush=True)

    with _Timer(summary, "library", executor.capacity) as step:
        library = library or build_library_step(executor, config.progress)
        step.detail = library.summary()
    with _Timer(summary, "dataset", executor.capacity) as step:
        step.detail = dataset_step(config, dataset_dir, executor)
    executor.release_workers()  # the generators they hold are not needed by the graph's pinned workers
    if config.backbone is not None:
        with _Timer(summary, "backbone") as step:
            step.detail = f"{config.backbone} (given)"
    dataset_hash = dataset_identity(dataset_dir)["dataset_hash"]
    nodes = task_graph(config, specs, runs, dataset_dir, out, dataset_hash)
    outcomes = _run_graph(summary, executor, nodes)

    backbone = config.backbone or f"offline:{output_dir(config.experiment.backbone)}"
    evaluations = _evaluations(runs, outcomes)
    settings = evaluation_settings(config, backbone)
    results = _results_and_figures(summary, config, evaluations, dataset_dir, settings, command)
    figure = outcomes.get(FIGURE_NODE)
    if figure is not None and figure.ok:
        summary.placement_figure = out / PLACEMENT_FIGURE
        _card_row(out / POLICY_FOLDER, results)
    summary.wall_s = time.perf_counter() - began
    _write_results(summary, config, results)
    summary.own_results = [
        _score_own_dataset(config, specs, runs, evaluations, own, executor, backbone, out, command)
        for own in config.own_datasets
    ]
    return summary


def own_dataset_subsets(dataset: Path) -> tuple[str, tuple[str, ...]]:
    """`(catalogue name, its subsets)` of a test-only dataset of a user's catalogue; ConfigError for any other."""
    from ocplace.sim.dataset.job import read_manifest

    config = read_manifest(dataset).get("config") or {}
    catalogue = config.get("catalogue") if isinstance(config, dict) else None
    if not isinstance(catalogue, dict):
        raise ConfigError(
            f"{dataset} is no dataset of your own catalogue (made by `ocplace generate --catalogue FILE`); the "
            "benchmark's own datasets are the experiment's"
        )
    return str(catalogue.get("name")), tuple(split["name"] for split in config["splits"])


def _score_own_dataset(
    config: PipelineConfig,
    specs: Mapping[str, MethodSpec[Any]],
    runs: list[MethodRun],
    evaluations: list[Evaluation],
    dataset: Path,
    executor: Executor,
    backbone: str,
    out: Path,
    command: object,
) -> Path:
    """Every row's run on the whole training set (its first seed) scored on `dataset`'s subsets, as `ocplace evaluate
    --runs-from OUT` would; OUT/<catalogue>.results.json and its tables. Resumed from OUT/evaluations/ as the rest."""
    from ocplace.eval.results import build_results
    from ocplace.eval.table import write_outputs
    from ocplace.experiments.evaluation import evaluate_runs

    name, subsets = own_dataset_subsets(dataset)
    trained = {e.key: None if e.run_dir is None else Path(e.run_dir) for e in evaluations}
    base = [
        dataclasses.replace(run, run_dir=trained[run.key])
        for run in runs
        if run.fraction == 1.0 and run.seed is None and run.backbone_seed is None and run.key in trained
    ]
    settings = dataclasses.replace(evaluation_settings(config, backbone), subsets=subsets)
    scored = evaluate_runs(specs, base, dataset, settings, executor, config.progress, out / "evaluations")
    path = out / f"{name}.results.json"
    write_outputs(build_results(scored, dataset, settings, command), path)
    print(f"your catalogue {name!r}: {', '.join(subsets)} scored into {path}", flush=True)
    return path


def _card_row(folder: Path, results: dict[str, Any] | None) -> None:
    """The exported Ours policy's Table I row, from this run's results, into its model card."""
    from ocplace.eval.table import table_one
    from ocplace.methods.export import write_table_row
    from ocplace.models.policy_folder import CONFIG_FILE

    if results is None or not (folder / CONFIG_FILE).is_file():  # the results are never lost over a model card
        return
    table = [line for line in table_one(results).splitlines() if line.startswith("|")]
    rows = [line for line in table if line.startswith("| Ours |")]
    if rows:  # the table's three header lines, then the row
        note = "(Table I of the `reproduce` run that exported it, its `results.md`.)"
        write_table_row(folder, "\n".join(table[:3] + rows) + "\n\n" + note)


def _run_graph(summary: PipelineSummary, executor: Executor, nodes: list[Node]) -> dict[str, Any]:
    """Runs the graph, printing each step as it starts and ends; records steps and errors in graph order
    (not the order they happened to end in), so results.json does not depend on the executor."""
    started: dict[str, float] = {}
    cpus: dict[str, int] = {}
    steps: dict[str, Step] = {}
    errors: dict[str, dict[str, Any]] = {}

    def on_start(key: str, task: Task) -> None:
        started[key], cpus[key] = time.perf_counter(), task.cpus
        print(f"[{key}] started", flush=True)

    def on_outcome(outcome: Outcome) -> None:
        if outcome.skipped_because is not None:
            print(f"[{outcome.key}] skipped: {outcome.skipped_because} failed", flush=True)
            return
        wall = time.perf_counter() - started.get(outcome.key, time.perf_counter())
        if outcome.error is None:
            detail = _node_detail(outcome.key, outcome.value)
        else:
            stage, _, key = outcome.key.partition(" ")
            errors[outcome.key] = _error(key or stage, stage, outcome.error)
            detail = f"FAILED: {type(outcome.error).__name__}: {outcome.error}"
        steps[outcome.key] = Step(outcome.key, wall, detail, cpus[outcome.key])
        print(steps[outcome.key].line(), flush=True)

    outcomes = run_graph(executor, nodes, on_outcome, on_start)
    summary.steps += [steps[node.key] for node in nodes if node.key in steps]
    summary.errors += [errors[node.key] for node in nodes if node.key in errors]
    return outcomes


def _evaluations(runs: list[MethodRun], outcomes: dict[str, Any]) -> list[Evaluation]:
    from ocplace.experiments.evaluation import read_stored_evaluation

    evaluated = [outcomes[f"evaluate {run.key}"] for run in runs]
    stored = [read_stored_evaluation(o.value[0]) for o in evaluated if o.ok]
    if any(evaluation is None for evaluation in stored):
        raise ResultsError("a stored evaluation changed after it was written (said above); run the command again")
    return [evaluation for evaluation in stored if evaluation is not None]


def _results_and_figures(
    summary: PipelineSummary,
    config: PipelineConfig,
    evaluations: list[Evaluation],
    dataset_dir: Path,
    settings: EvalSettings,
    command: object,
) -> dict[str, Any]:
    """The results (written by `_write_results` once the run's steps and total wall are known) and the
    paper's figures drawn from them."""
    from ocplace.eval.results import build_results

    out = summary.out
    with _Timer(summary, "results") as step:
        results = build_results(evaluations, dataset_dir, settings, command)
        summary.results_path = out / "results.json"
        step.detail = (
            f"{summary.results_path}, {summary.results_path.with_suffix('.md')}, {out / SUMMARY_FILE}, "
            f"{out / OUTCOMES_FILE}"
        )
    if evaluations:
        with _Timer(summary, "paper figures") as step:
            try:
                from ocplace.eval.figures import write_figures

                summary.figures = write_figures(results, out / "figures", dataset_dir, config.experiment.seed)
                step.detail = ", ".join(str(path) for path in summary.figures)
            except Exception as error:
                summary.errors.append(_error("figures", "figures", error))
                step.detail = f"FAILED: {type(error).__name__}: {error}"
    return results


def _write_results(summary: PipelineSummary, config: PipelineConfig, results: dict[str, Any]) -> None:
    """results.json, its tables and its summary, once, with the run itself: its config, each step's wall
    and CPUs, its errors and its total wall (known only at the end: the figures come after the results
    they draw)."""
    from ocplace.eval.results import summarise, write_outcomes, write_results
    from ocplace.eval.table import terminal_summary, write_outputs

    results["pipeline"] = {
        "config": _config_json(config),
        "steps": [dataclasses.asdict(s) for s in summary.steps],
        "errors": summary.errors,
        "total_wall_s": summary.wall_s,
    }
    assert summary.results_path is not None, "set by _results_and_figures"
    summary.markdown = write_outputs(results, summary.results_path)
    summary.terminal = terminal_summary(results)
    write_results(summary.out / SUMMARY_FILE, summarise(results))
    write_outcomes(summary.out / OUTCOMES_FILE, results)


def _error(key: str, stage: str, error: BaseException) -> dict[str, Any]:
    print(f"ERROR in step {stage} of {key}:", flush=True)
    traceback.print_exception(error)
    return {"key": key, "stage": stage, "message": f"{type(error).__name__}: {error}"}


def _config_json(config: PipelineConfig) -> dict[str, Any]:
    """The experiment and its inputs; not the executor, which changes nothing in the results."""

    described: dict[str, Any] = serial.to_dict(
        {field: value for field, value in dataclasses.asdict(config).items() if field != "executor"}
    )
    return described
