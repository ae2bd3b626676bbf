"""`ocplace reproduce` at smoke scale.

The default tests run the pipeline on the session's smoke dataset and tiny backbone with test-local
methods (seconds); the slow test runs `ocplace reproduce --experiment smoke` from nothing with every
method registered at the time (their smoke trainings take minutes on a shared 2-core machine).
"""

import dataclasses
import json
from pathlib import Path

import eval_methods
import pytest

from ocplace import configs
from ocplace.errors import ConfigError, OcplaceError
from ocplace.eval import figures, results
from ocplace.experiments import layout, pipeline
from ocplace.experiments.evaluation import rerun
from ocplace.experiments.experiment import TaskCpus
from ocplace.methods import registry
from ocplace.runtime import ExecutorConfig
from ocplace.train.schedule import rescheduled
from ocplace.vocabulary import TEST_SUBSETS

LOCAL = ("oracle", "centre", "failing")
PNG = b"\x89PNG\r\n\x1a\n"
NOTEBOOK = Path(__file__).resolve().parents[1] / "notebooks" / "02_results.ipynb"


@pytest.fixture(scope="module")
def specs():
    return {name: eval_methods.SPECS[name] for name in LOCAL}


@pytest.fixture(scope="module")
def config(smoke_dataset, tiny_backbone_spec):
    smoke = configs.get("smoke")
    experiment = dataclasses.replace(
        smoke,
        dataset=dataclasses.replace(smoke.dataset, physical_scenes=1),
        evaluation=dataclasses.replace(smoke.evaluation, fractions=(0.5, 1.0), fraction_methods=("oracle",)),
    )
    return pipeline.PipelineConfig(experiment, backbone=tiny_backbone_spec, dataset=smoke_dataset, progress=False)


@pytest.fixture(scope="module")
def first_run(config, specs, library, tmp_path_factory):
    out = tmp_path_factory.mktemp("reproduce")
    return pipeline.run_pipeline(config, out, specs=specs, library=library, command=["pytest"])


def test_smoke_pipeline_trains_and_evaluates_every_method(first_run, specs):
    assert first_run.errors == []
    saved = results.read_results(first_run.results_path)
    assert sorted(e["key"] for e in saved["evaluations"]) == sorted([*specs, "oracle@0.5"])
    for entry in saved["evaluations"]:
        for subset in TEST_SUBSETS:
            assert entry["subsets"][subset]["aggregate"]["overall"]["scenes"] == 8, (entry["key"], subset)
        trains = specs[entry["method"]].train is not None
        assert (entry["run_dir"] is not None) == trains
        physical = entry["subsets"]["seen"]["aggregate"]["overall"]["physical_scenes"]
        assert physical == (1 if entry["fraction"] == 1.0 else 0)
    oracle = next(e for e in saved["evaluations"] if e["key"] == "oracle")
    assert oracle["subsets"]["unseen_inst"]["aggregate"]["overall"]["success"] == 1.0
    assert json.loads((first_run.out / "runs/oracle/fraction-0.50/dataset.json").read_text())["fraction"] == 0.5
    markdown = first_run.results_path.with_suffix(".md").read_text()
    for name, spec in specs.items():
        assert f"| {spec.label} |" in markdown, name
    assert "| Oracle | 100.00 |" in markdown and "Sample efficiency" in markdown
    # Fig. 5 and Fig. 7 (two fractions of the oracle); no Fig. 6 without Ours and CLIPort-Place.
    assert [path.name for path in first_run.figures] == [figures.FIG5, figures.FIG7]
    assert all(path.read_bytes()[:8] == PNG for path in first_run.figures)
    names = [step.name for step in first_run.steps]
    assert names[:3] == ["library", "dataset", "backbone"] and names[-2:] == ["results", "paper figures"]
    assert "already complete" in first_run.steps[1].detail


def test_the_run_ends_with_table_one_and_one_line_of_failures_by_reason(first_run):
    assert "| Oracle | 100.00 |" in first_run.terminal and "| Always fails |" in first_run.terminal
    assert "Method failures" in first_run.markdown and "Method failures" not in first_run.terminal
    scenes = 8 * len(TEST_SUBSETS)  # the failing row fails every scene; the others place every one
    last = first_run.terminal.splitlines()[-1]
    assert (
        last == f"Scenes without a placement, by reason, over every row: no reference found (test method) {scenes} "
        "(each scene in the .md)."
    )
    assert "total" in first_run.report() and "[dataset]" not in first_run.report()


def test_results_record_each_steps_cpus_and_the_total_wall(first_run, config):
    recorded = results.read_results(first_run.results_path)["pipeline"]
    assert [step["name"] for step in recorded["steps"]] == [step.name for step in first_run.steps]  # figures too
    cpus = {step["name"]: step["cpus"] for step in recorded["steps"]}
    assert cpus["library"] == cpus["dataset"] == ExecutorConfig().cpus()  # the pool's workers
    trains = [name for name in cpus if name.startswith("train ")]
    assert trains and all(cpus[name] == config.experiment.cpus.train for name in trains)
    assert all(cpus[name] == 1 for name in cpus if name.startswith("evaluate "))
    assert recorded["total_wall_s"] == first_run.wall_s
    assert results.read_results(first_run.out / pipeline.SUMMARY_FILE)["pipeline"] == recorded


def test_smoke_pipeline_resumes_without_redoing_work(first_run, config, specs, library):
    again = pipeline.run_pipeline(config, first_run.out, specs=specs, library=library, command=["pytest"])
    assert again.errors == []
    assert all(step.detail.startswith("stored") for step in again.steps if step.name.startswith("evaluate"))
    assert all(
        step.detail.startswith(("done before", "nothing")) for step in again.steps if step.name.startswith("train")
    )
    assert results.compare(results.read_results(first_run.results_path), results.read_results(again.results_path)) == []


def test_summary_keeps_every_table_and_counts_the_scenes(first_run):
    from ocplace.eval import table

    full = results.read_results(first_run.results_path)
    summary = results.read_results(first_run.out / pipeline.SUMMARY_FILE)
    assert summary["summary"] is True
    assert table.render(summary).split("**Method failures**")[0] == table.render(full).split("**Method failures**")[0]
    for entry, kept in zip(full["evaluations"], summary["evaluations"], strict=True):
        for subset, body in entry["subsets"].items():
            assert kept["subsets"][subset]["aggregate"] == body["aggregate"] and kept["subsets"][subset]["scenes"] == []
            assert kept["subsets"][subset]["omitted_scenes"] == len(body["scenes"])
            assert kept["subsets"][subset]["failed_scenes"] == sum(s["failure"] is not None for s in body["scenes"])
    failing = next(e for e in summary["evaluations"] if e["method"] == "failing")
    assert (
        f"- {failing['label']} (failing): {8 * len(TEST_SUBSETS)} scenes (listed in the full results JSON)"
        in table.failure_list(summary)
    )
    assert len(first_run.results_path.read_bytes()) > 2 * len((first_run.out / pipeline.SUMMARY_FILE).read_bytes())
    with pytest.raises(OcplaceError, match="summary without per-scene outcomes"):
        rerun(summary)


def test_outcomes_file_puts_every_scene_back_into_the_summary(first_run, tmp_path):
    from ocplace.eval import statistics, table

    full = results.read_results(first_run.results_path)
    summary = results.read_results(first_run.out / pipeline.SUMMARY_FILE)
    outcomes = first_run.out / pipeline.OUTCOMES_FILE
    restored = results.with_outcomes(summary, outcomes)
    assert statistics.derive(restored) == summary["derived"] == statistics.derive(full)
    # Every table as from the full results, the failures listed again (by their error type).
    assert table.render(restored).split("**Method failures**")[0] == table.render(full).split("**Method failures**")[0]
    for entry, back in zip(full["evaluations"], restored["evaluations"], strict=True):
        for subset, body in entry["subsets"].items():
            kept = [{name: scene[name] for name in results.OUTCOME_FIELDS} for scene in body["scenes"]]
            for scene in kept:
                scene["failure"] = scene["failure"] and scene["failure"].split(":")[0]
            assert back["subsets"][subset]["scenes"] == kept
    failing = [line for line in table.failure_list(restored).splitlines() if "`" in line]
    assert failing and all(
        line.endswith(": no reference found (test method)".split(":")[0] + "") or ": " in line for line in failing
    )
    assert results.write_outcomes(tmp_path / "again.jsonl.gz", full).read_bytes() == outcomes.read_bytes()
    table_one_only = results.with_outcomes(summary, results.write_outcomes(tmp_path / "t1.jsonl.gz", full, (1.0,)))
    assert table_one_only["summary"] and statistics.derive(table_one_only) == summary["derived"]  # intervals: rows
    (tmp_path / "cut.jsonl.gz").write_bytes(outcomes.read_bytes()[:-40])
    with pytest.raises(OcplaceError, match="not an outcomes file|scenes of"):
        results.with_outcomes(summary, tmp_path / "cut.jsonl.gz")


def test_table_one_shows_mean_and_spread_over_seeds(first_run):
    from ocplace.eval import table

    saved = results.read_results(first_run.results_path)
    centre = next(e for e in saved["evaluations"] if e["key"] == "centre")
    repeat = json.loads(json.dumps(centre)) | {"key": "centre~seed1", "seed": 1}
    for subset in repeat["subsets"].values():
        for level in subset["aggregate"].values():
            level["success"] = 0.5
    saved["evaluations"].append(repeat)
    overall = centre["subsets"]["seen"]["aggregate"]["overall"]["success"]
    mean, spread = (overall + 0.5) / 2, abs(overall - 0.5) / 2**0.5  # sample standard deviation of two values
    lines = table.table_one(saved).splitlines()
    assert lines[0].endswith("(mean ± standard deviation over 2 seeds, where a row has them)")  # centre only
    row = next(line for line in lines if line.startswith("| Table centre |")).split("|")[2:-1]
    assert row[4].strip() == f"{100 * mean:.2f} ± {100 * spread:.2f}"
    assert next(line for line in lines if line.startswith("| Oracle |")).count("100.00") == 5 * len(TEST_SUBSETS)
    assert [e["key"] for e in table.full_runs(saved)] == ["oracle", "centre", "failing"]  # repeats are not rows


def test_fig6_cases_prefer_scenes_where_the_methods_disagree(first_run, tmp_path):
    saved = results.read_results(first_run.results_path)
    cases = figures.choose_cases(saved, methods=("oracle", "centre"))
    outcomes = {
        (e["method"], s): {o["id"]: o for o in e["subsets"][s]["scenes"]}
        for e in saved["evaluations"]
        if e["fraction"] == 1.0
        for s in TEST_SUBSETS
    }
    for subset in TEST_SUBSETS:
        oracle, centre = outcomes["oracle", subset], outcomes["centre", subset]
        chosen = [scene_id for s, scene_id in cases if s == subset]
        levels = [oracle[scene_id]["level"] for scene_id in chosen]
        assert levels == [level for level in figures.CASE_LEVELS if any(o["level"] == level for o in oracle.values())]
        for scene_id, level in zip(chosen, levels):
            disagreeing = [i for i, o in oracle.items() if o["level"] == level and o["success"] != centre[i]["success"]]
            assert scene_id == (disagreeing or [i for i, o in oracle.items() if o["level"] == level])[0]
    path = figures.plot_cases(saved, tmp_path / "cases.png", methods=("oracle", "centre"))
    assert path.read_bytes()[:8] == PNG
    with pytest.raises(OcplaceError, match="no full-data evaluation of \\['cliport'\\]"):
        figures.choose_cases(saved, methods=("oracle", "cliport"))


def test_figures_command_writes_what_the_results_allow(first_run, tmp_path, capsys):
    from ocplace.cli import main

    assert main(["figures", str(first_run.results_path), "--out", str(tmp_path)]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == [figures.FIG5, figures.FIG7]
    summary = results.summarise(results.read_results(first_run.results_path))
    full_data = [e for e in summary["evaluations"] if e["fraction"] == 1.0]
    summary["evaluations"] += [dict(e, method=name) for e, name in zip(full_data, figures.CASE_METHODS)]
    assert [p.name for p in figures.write_figures(summary, tmp_path / "from_summary")] == [figures.FIG5, figures.FIG7]
    assert main(["figures", str(tmp_path / "missing.json"), "--out", str(tmp_path)]) == 2
    assert "missing or not JSON" in capsys.readouterr().err


def test_figures_take_a_format_and_a_dpi_and_go_beside_their_results(first_run, tmp_path, capsys):
    import shutil

    from ocplace.cli import main

    moved = tmp_path / "run"
    shutil.copytree(first_run.out, moved, ignore=shutil.ignore_patterns("figures"))
    assert main(["figures", str(moved / "results.json"), "--format", "svg", "--dpi", "72"]) == 0
    written = sorted(p.name for p in (moved / "figures").iterdir())
    assert written == ["fig5_placement_distributions.svg", "fig7_sample_efficiency.svg"]
    assert (moved / "figures" / written[0]).read_text().lstrip().startswith("<?xml")
    bad = ["figures", str(moved / "results.json"), "--out", str(tmp_path / "bad")]
    with pytest.raises(SystemExit):  # refused as the flag is read (issue 60)
        main([*bad, "--dpi", "0"])
    assert "argument --dpi: 0 is out of range: give a whole number from 10 to 1,200" in capsys.readouterr().err
    with pytest.raises(SystemExit):  # argparse's usage error, naming the choices
        main([*bad, "--format", "bmp"])
    assert "invalid choice: 'bmp' (choose from 'png', 'pdf', 'svg')" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()


def test_fig7_points_are_the_mean_and_spread_over_seeds(first_run):
    from ocplace.eval.efficiency import efficiency_curves

    saved = results.read_results(first_run.results_path)
    oracle = [e for e in saved["evaluations"] if e["method"] == "oracle"]
    halved = [
        dict(e, seed=1, subsets={s: dict(b, aggregate=_halved(b["aggregate"])) for s, b in e["subsets"].items()})
        for e in oracle
    ]
    curves = efficiency_curves(dict(saved, evaluations=saved["evaluations"] + halved))
    (fraction, mean, spread, runs), _ = curves["Oracle"]["seen"]
    assert (fraction, runs) == (0.5, 2) and mean == pytest.approx(75.0) and spread == pytest.approx(25.0)


def _halved(aggregate):
    return {
        level: dict(cell, success=cell["success"] / 2)
        if isinstance(cell, dict) and cell.get("success") is not None
        else cell
        for level, cell in aggregate.items()
    }


@pytest.mark.parametrize("file_name, images_expected", [("results.json", 4), (pipeline.SUMMARY_FILE, 3)])
def test_results_notebook_executes_on_the_smoke_results(first_run, tmp_path, monkeypatch, file_name, images_expected):
    from notebook_run import executed_outputs, printed

    monkeypatch.setenv("OCPLACE_RESULTS", str(first_run.out / file_name))
    outputs = executed_outputs(NOTEBOOK, tmp_path)
    text = printed(outputs)
    assert "4 evaluations (3 on the whole training set)" in text
    markdown = "".join(o["data"].get("text/markdown", "") for o in outputs if o.output_type == "display_data")
    assert "Table I: success rate of the mode" in markdown and "| Oracle | 100.00 |" in markdown
    images = [o for o in outputs if o.output_type == "display_data" and "image/png" in o["data"]]
    assert len(images) == images_expected  # success bars, stages, Fig. 7, Fig. 6 (not from a summary)
    cases = first_run.out / "figures" / "cases.png"  # beside the results, never in the notebook's folder
    assert cases.exists() == (images_expected == 4) or file_name == pipeline.SUMMARY_FILE
    assert not (tmp_path / "cases.png").exists()


def test_scale_configs():
    demo, default = configs.get("demo"), configs.get("default")
    sizes = (default.dataset.train_scenes, default.dataset.test_scenes, default.evaluation.fractions)
    assert sizes == (2000, 400, (0.25, 0.5, 0.75, 1.0))
    assert demo.evaluation.fractions == (1.0,) and str(demo.out) == "out/demo"
    assert str(default.out) == "out/reproduce"
    demo, default = pipeline.PipelineConfig(demo), pipeline.PipelineConfig(default)
    specs = registry.method_specs()
    assert [s.name for s in pipeline.selected_specs(demo, specs)] == ["ours", "ours_joint", "no_adapter", "no_llm"]
    assert [s.name for s in pipeline.selected_specs(default, specs)] == list(specs)
    runs = pipeline.planned_runs(default, list(eval_methods.SPECS.values()))
    assert [run.key for run in runs] == ["oracle", "centre", "failing", "flaky", "random"]
    ours_like = dataclasses.replace(eval_methods.SPECS["oracle"], name="ours")
    assert [run.fraction for run in pipeline.planned_runs(default, [ours_like])] == [0.25, 0.5, 0.75, 1.0]
    three_seeds = dataclasses.replace(
        default, experiment=with_seeds(default.experiment, 3, fractions=(0.5, 1.0), methods=("ours",))
    )
    assert [run.key for run in pipeline.planned_runs(three_seeds, [ours_like, eval_methods.SPECS["centre"]])] == [
        *("ours@0.5", "ours@0.5~seed1", "ours@0.5~seed2", "ours", "ours~seed1", "ours~seed2"),
        *("centre", "centre~seed1", "centre~seed2"),
    ]
    only_ours = dataclasses.replace(
        default,
        experiment=with_seeds(default.experiment, 3, fractions=(0.5, 1.0), methods=("ours",), seed_methods=("ours",)),
    )
    assert [run.key for run in pipeline.planned_runs(only_ours, [ours_like, eval_methods.SPECS["centre"]])] == [
        *("ours@0.5", "ours@0.5~seed1", "ours@0.5~seed2", "ours", "ours~seed1", "ours~seed2"),
        "centre",
    ]
    whole_set_only = dataclasses.replace(
        only_ours,
        experiment=dataclasses.replace(
            only_ours.experiment,
            evaluation=dataclasses.replace(only_ours.experiment.evaluation, seed_fractions=(1.0,)),
        ),
    )
    assert [run.key for run in pipeline.planned_runs(whole_set_only, [ours_like])] == [
        *("ours@0.5", "ours", "ours~seed1", "ours~seed2")
    ]


def test_task_graph_of_the_demo(tmp_path):
    rows = ("ours", "no_adapter", "no_llm", "no_pretrain")  # a row with its own tower beside the shared ones
    demo = pipeline.PipelineConfig(with_seeds(configs.get("demo"), 2, methods=rows))
    specs = registry.method_specs()
    runs = pipeline.planned_runs(demo, pipeline.selected_specs(demo, specs))
    nodes = {node.key: node for node in pipeline.task_graph(demo, specs, runs, tmp_path / "data", tmp_path, "hash")}
    assert list(nodes)[:2] == ["backbone", "prepare ours+no_llm"]  # the shared features: made once, for both
    assert nodes["backbone"].make({}).cpus == demo.experiment.cpus.pretrain == 2
    assert nodes["train no_llm~seed1"].after == ("backbone", "prepare ours+no_llm")
    assert nodes["train no_pretrain"].after == ("backbone",)
    assert nodes["evaluate no_adapter~seed1"].after == ("backbone",)  # learns nothing: scored once it exists
    assert nodes["evaluate ours~seed1"].after == ("backbone", "train ours~seed1")
    task = nodes["train ours~seed1"].make({"backbone": "offline:/b", "prepare ours+no_llm": "ready"})
    spec, context = task.args
    assert spec.name == "ours" and context.backbone == "offline:/b"
    assert task.pinned and task.cpus == 2 and context.seed == 1 and context.out_dir.name == "fraction-1.00-seed-1"
    assert nodes["prepare ours+no_llm"].make({"backbone": "offline:/b"}).cpus == 2
    assert (
        nodes["evaluate ours~seed1"].make({"backbone": "offline:/b", "train ours~seed1": (tmp_path, False)}).cpus == 1
    )
    evaluations = [key.removeprefix("evaluate ") for key in nodes if key.startswith("evaluate ")]
    # The first evaluation to encode the shared test features starts beside no_pretrain (its own backbone),
    # not beside the evaluations that read those features.
    assert evaluations[:3] == ["ours", "no_pretrain", "no_pretrain~seed1"]
    assert sorted(evaluations) == sorted(run.key for run in runs)
    assert list(nodes)[-1] == "figure ours" and nodes["figure ours"].after == ("backbone", "train ours")
    figure = nodes["figure ours"].make({"backbone": "offline:/b", "train ours": (tmp_path / "run", False)})
    assert figure.pinned and figure.cpus == 1 and figure.args[0] == tmp_path / "run"


def test_backbone_seeds_share_the_base_pretrainings_renders(tmp_path):
    demo = pipeline.PipelineConfig(
        dataclasses.replace(
            configs.get("demo"),
            evaluation=dataclasses.replace(configs.get("demo").evaluation, backbone_seeds=3, seed_methods=("ours",)),
        )
    )
    specs = registry.method_specs()
    runs = pipeline.planned_runs(demo, pipeline.selected_specs(demo, specs))
    nodes = {node.key: node for node in pipeline.task_graph(demo, specs, runs, tmp_path / "data", tmp_path, "hash")}
    assert [key for key in nodes if key.startswith("backbone")] == ["backbone", "backbone seed 1", "backbone seed 2"]
    assert nodes["backbone"].after == () and nodes["backbone seed 1"].after == ("backbone",)
    assert nodes["backbone seed 2"].after == ("backbone seed 1",)  # one after another: one renders for the rest
    tasks = [nodes[key].make({}) for key in ("backbone", "backbone seed 2")]
    assert [task.args[0].optim.seed for task in tasks] == [0, 2] and all(task.args[-1] is True for task in tasks)
    one = pipeline.PipelineConfig(configs.get("demo"))
    runs = pipeline.planned_runs(one, pipeline.selected_specs(one, specs))
    alone = next(node for node in pipeline.task_graph(one, specs, runs, tmp_path / "data", tmp_path, "hash"))
    assert alone.key == "backbone" and alone.make({}).args[-1] is False  # one seed: its renders go with its run


def test_evaluation_order_puts_one_encoder_of_the_shared_features_first():
    specs = registry.method_specs()
    runs = [registry.method_run(specs[name], None, 1.0, None) for name in ("no_adapter", "ours", "grids", "no_llm")]
    assert [run.method for run in pipeline.evaluation_order(runs, specs)] == ["no_adapter", "grids", "ours", "no_llm"]
    own = [run for run in runs if run.method == "grids"]
    assert pipeline.evaluation_order(own, specs) == own


def test_task_widths_are_part_of_the_experiment():
    assert configs.get("smoke").cpus == TaskCpus(pretrain=2, train=1)
    assert configs.get("demo").cpus == configs.get("default").cpus == TaskCpus(pretrain=2, train=2)
    with pytest.raises(ConfigError, match="at least 1"):
        TaskCpus(train=0)


def with_seeds(experiment, seeds: int, **plan):
    return dataclasses.replace(experiment, evaluation=dataclasses.replace(experiment.evaluation, seeds=seeds, **plan))


@pytest.mark.slow
def test_reproduce_smoke_from_nothing_with_every_registered_method(tmp_path, capsys):
    from ocplace.cli import main

    registered = registry.method_specs()
    assert main(["reproduce", "--experiment", "smoke", "--out", str(tmp_path), "--no-progress"]) == 0
    printed = capsys.readouterr().out
    saved = results.read_results(tmp_path / "results.json")
    assert [e["key"] for e in saved["evaluations"]] == list(registered)
    assert saved["pipeline"]["errors"] == [] and saved["command"]["arguments"]["experiment"] == "smoke"
    for spec in registered.values():
        assert f"| {spec.label} |" in printed
    for entry in saved["evaluations"]:
        assert entry["description"], entry["key"]
        assert all(entry["subsets"][s]["aggregate"]["overall"]["scenes"] == 8 for s in TEST_SUBSETS)


def test_reproduce_options_reach_the_config(tmp_path, monkeypatch):
    from ocplace.cli import build_parser

    calls = []

    def record(config, out, command):
        calls.append((config, out))
        return pipeline.PipelineSummary(out)

    def reproduce(*options):
        args = build_parser().parse_args(["reproduce", *options])
        assert args.func(args) == 0
        return calls.pop()

    monkeypatch.setattr(pipeline, "run_pipeline", record)
    config, out = reproduce(
        *("--experiment", "default", "--out", str(tmp_path / "out"), "--backbone", "offline:spec"),
        *("--methods", "no_adapter, grids", "--workers", "3", "--dataset", str(tmp_path / "dataset")),
        *("--fractions", "1", "0.5", "1", "--physical", "5", "--no-progress", "--seeds", "2", "--ray"),
    )
    assert out == tmp_path / "out"
    default = configs.get("default")
    assert config == pipeline.PipelineConfig(
        dataclasses.replace(
            default,
            dataset=dataclasses.replace(default.dataset, physical_scenes=5),
            evaluation=dataclasses.replace(
                default.evaluation, methods=("no_adapter", "grids"), fractions=(0.5, 1.0), seeds=2
            ),
        ),
        backbone="offline:spec",
        executor=ExecutorConfig(kind="ray", workers=3, progress=False),
        dataset=tmp_path / "dataset",
        progress=False,
    )
    config, out = reproduce("--methods", "all", "--physical", "-1")  # the demo scale by default
    demo = configs.get("demo")
    assert out == demo.out
    assert config == pipeline.PipelineConfig(
        dataclasses.replace(
            demo,
            dataset=dataclasses.replace(demo.dataset, physical_scenes=None),
            evaluation=dataclasses.replace(demo.evaluation, methods=None),
        )
    )
    config, _ = reproduce("--experiment", "smoke")
    assert config == pipeline.PipelineConfig(configs.get("smoke"))
    with pytest.raises(SystemExit):
        build_parser().parse_args(["reproduce", "--fractions", "0"])


def test_reproduce_set_reaches_the_experiment(tmp_path, monkeypatch):
    from ocplace.cli import build_parser

    calls = []

    def record(config, out, command):
        calls.append((config, out))
        return pipeline.PipelineSummary(out)

    monkeypatch.setattr(pipeline, "run_pipeline", record)
    args = build_parser().parse_args(
        [
            *("reproduce", "--experiment", "smoke", "--methods", "all", "--workers", "2"),
            *("--set", "recipes.ours.schedule.steps=5000", "--set", "dataset.train_scenes=100"),
            *("--set", "evaluation.methods=no_adapter, grids", "--set", f"out={tmp_path / 'elsewhere'}"),
        ]
    )
    assert args.func(args) == 0
    smoke = configs.get("smoke")
    config, out = calls.pop()
    assert out == tmp_path / "elsewhere"
    assert config == pipeline.PipelineConfig(
        dataclasses.replace(
            smoke,
            out=tmp_path / "elsewhere",
            recipes={**smoke.recipes, "ours": rescheduled(smoke.recipes["ours"], steps=5000)},
            dataset=dataclasses.replace(smoke.dataset, train_scenes=100),
            evaluation=dataclasses.replace(smoke.evaluation, methods=("no_adapter", "grids")),  # after --methods
        ),
        executor=ExecutorConfig(workers=2),
    )


@pytest.mark.parametrize(
    "key",
    ["recipes.ours.seed", "recipes.no_llm.fraction", "recipes.no_pretrain.seed"],
)
def test_reproduce_refuses_to_set_what_each_run_sets(key, tmp_path, monkeypatch, capsys):
    from ocplace.cli import main

    monkeypatch.setattr(pipeline, "run_pipeline", lambda *args, **kwargs: pytest.fail("ran with a refused key"))
    assert main(["reproduce", "--experiment", "smoke", "--out", str(tmp_path), "--set", f"{key}=3"]) == 2
    assert f"{key} is set for each run from" in capsys.readouterr().err


def test_backbone_seeds_plan_a_pretraining_each_and_repeat_only_the_seeded_backbone_methods(tmp_path):
    """The plan of the slow end-to-end test below, in the default suite: no pretraining, no training."""
    smoke = configs.get("smoke")
    plan = dataclasses.replace(
        smoke.evaluation, methods=("ours", "no_adapter"), seed_methods=("ours",), backbone_seeds=2, subsets=("seen",)
    )
    config = pipeline.PipelineConfig(dataclasses.replace(smoke, evaluation=plan), dataset=tmp_path, progress=False)
    specs = registry.method_specs()
    runs = pipeline.planned_runs(config, [specs["ours"], specs["no_adapter"]])
    assert sorted(run.key for run in runs) == ["no_adapter", "ours", "ours~backbone1"]
    nodes = {node.key: node for node in pipeline.task_graph(config, specs, runs, tmp_path, tmp_path / "out", "h")}
    assert pipeline.backbone_key(None) in nodes and pipeline.backbone_key(1) in nodes
    assert pipeline.backbone_key(1) in nodes["train ours~backbone1"].after
    assert pipeline.backbone_key(1) in nodes["evaluate ours~backbone1"].after
    assert pipeline.backbone_key(1) not in nodes["evaluate no_adapter"].after
    assert layout.run_directory(tmp_path, "ours", 1.0, None, 1).name == "fraction-1.00-backbone-1"


@pytest.mark.slow  # 90 s, a tenth of the default suite's 15 minutes: `make test-all` runs it
def test_backbone_seeds_pretrain_train_and_score_on_each_backbone(smoke_dataset, library, borrowed_cache, tmp_path):
    from ocplace.eval import table
    from ocplace.models.offline_recipes import output_dir
    from ocplace.models.trained_adapters import load_adapters

    smoke = configs.get("smoke")
    plan = dataclasses.replace(
        smoke.evaluation, methods=("ours", "no_adapter"), seed_methods=("ours",), backbone_seeds=2, subsets=("seen",)
    )
    dataset = dataclasses.replace(smoke.dataset, physical_scenes=0)
    experiment = dataclasses.replace(smoke, evaluation=plan, dataset=dataset)
    config = pipeline.PipelineConfig(experiment, dataset=smoke_dataset, progress=False)
    summary = pipeline.run_pipeline(config, tmp_path / "out", library=library, command=["pytest"])
    assert summary.errors == []
    saved = results.read_results(summary.results_path)
    entries = {entry["key"]: entry for entry in saved["evaluations"]}
    assert sorted(entries) == ["no_adapter", "ours", "ours~backbone1"]  # only the seeded method is repeated
    repeat_dir = output_dir(experiment.backbone_recipe(1))
    assert repeat_dir != output_dir(experiment.backbone) and (repeat_dir / "fingerprint.txt").is_file()
    assert (
        entries["ours~backbone1"]["backbone"] == f"offline:{repeat_dir}"
        and entries["ours~backbone1"]["backbone_seed"] == 1
    )
    fingerprints = {key: entry["description"]["backbone"]["fingerprint"] for key, entry in entries.items()}
    assert fingerprints["ours"] == fingerprints["no_adapter"] != fingerprints["ours~backbone1"]
    run_dir = Path(entries["ours~backbone1"]["run_dir"])
    assert run_dir.name == "fraction-1.00-backbone-1"
    assert load_adapters(run_dir / "weights.safetensors").backbone_fingerprint == fingerprints["ours~backbone1"]
    row = next(line for line in table.table_one(saved).splitlines() if line.startswith("| Ours |"))
    assert "±" in row and "over 2 seeds, where a row has them" in table.table_one(saved)
    assert results.compare(saved, rerun(saved, progress=False)) == []  # the repeat reloads its own backbone


def test_a_results_file_moved_with_its_dataset_still_finds_it(first_run, smoke_dataset, tmp_path):
    """Issue 44: results stored absolute paths only, so a moved results folder failed with advice to regenerate."""
    import shutil

    from ocplace.errors import EvaluationError

    tree = tmp_path / "tree"
    shutil.copytree(smoke_dataset, tree / "data")
    saved = results.read_results(first_run.results_path)
    saved["dataset"]["dir"] = str(tree / "data")
    results.write_results(tree / "out" / "results.json", saved)
    assert json.loads((tree / "out" / "results.json").read_text())["dataset"]["dir_relative"] == "../data"
    tree.rename(tmp_path / "moved")
    moved = results.read_results(tmp_path / "moved" / "out" / "results.json")
    assert moved["dataset"]["dir"] == str((tmp_path / "moved" / "data").resolve())
    assert [e["run_dir"] for e in moved["evaluations"]] == [e["run_dir"] for e in saved["evaluations"]]  # still there
    (tmp_path / "moved" / "data").rename(tmp_path / "elsewhere")
    with pytest.raises(EvaluationError, match="pass --dataset DIR to `ocplace figures`"):
        figures.write_figures(results.read_results(tmp_path / "moved" / "out" / "results.json"), tmp_path / "figures")


def test_the_readmes_demo_figures_are_written_from_a_results_file(first_run, tmp_path):
    """Issue 44: the README's demo figures were typed by hand; `scripts/readme_figures.py` writes them."""
    import subprocess
    import sys

    root = Path(__file__).resolve().parents[1]
    readme = tmp_path / "README.md"
    readme.write_text((root / "README.md").read_text())
    script = root / "scripts" / "readme_figures.py"
    command = [sys.executable, str(script), str(first_run.results_path), "--readme", str(readme)]
    done = subprocess.run(command, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    written = readme.read_text()
    saved = results.read_results(first_run.results_path)
    oracle = next(e for e in saved["evaluations"] if e["key"] == "oracle")
    seen = 100 * oracle["subsets"]["seen"]["aggregate"]["overall"]["success"]
    assert f"| Oracle | {seen:.1f} |" in written
    assert "| Oracle@" not in written and written.count("<!-- demo-table -->") == 1  # whole-training-set runs only
    assert written.split("<!-- demo-table -->")[0] == (root / "README.md").read_text().split("<!-- demo-table -->")[0]
    command = [*command[:3], "--paper", "--readme", str(readme), "--source", "docs/results/x.summary.json"]
    done = subprocess.run(command, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    paper = readme.read_text().split("<!-- paper-table -->")[1]
    assert (
        f"| Oracle | {seen:.2f} |" in paper and "| the paper's Ours (real CLIP) | 97.75 | 87.25 | 77.1 | - |" in paper
    )
    assert "from `docs/results/x.summary.json`" in paper and readme.read_text().count(f"| Oracle | {seen:.1f} |") == 1


def test_a_label_with_a_pipe_or_a_newline_stays_in_its_cell(first_run):
    from ocplace.eval import table

    saved = results.read_results(first_run.results_path)
    for entry in saved["evaluations"]:
        if entry["method"] == "failing":
            entry["label"] = "Mine | new\nline"
    text = table.table_one(saved)
    [mine] = [line for line in text.splitlines() if line.startswith("| Mine")]
    [oracle] = [line for line in text.splitlines() if line.startswith("| Oracle |")]
    assert mine.startswith("| Mine \\| new line |") and mine.count(" | ") == oracle.count(" | ")  # as many cells
    assert "- Mine \\| new line (failing): 32 scenes" in table.failure_list(saved).splitlines()


@pytest.mark.slow  # the default suite's 15 min budget on 2 cores (docs/performance.md)
def test_reproduce_scores_its_rows_on_a_catalogues_dataset_too(first_run, config, specs, library, tmp_path):
    """Issue 59: `reproduce --score-catalogue DIR` scores every row's run (the whole training set, its first seed) on
    a test-only dataset of a user's catalogue, into OUT/<catalogue>.results.json, resuming the rest; a benchmark
    dataset given there is refused before any work."""
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
    from example_catalogue import write_example

    from ocplace.sim.dataset.config import catalogue_config
    from ocplace.sim.dataset.job import generate_dataset
    from ocplace.sim.library import default_config
    from ocplace.sim.library.build import build_catalogue
    from ocplace.sim.library.catalogue_library import catalogue_record
    from ocplace.sim.library.user_catalogue import read_catalogue

    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("OCPLACE_CACHE", str(tmp_path / "cache"))
        (tmp_path / "cache").mkdir()
        (tmp_path / "cache" / "library").symlink_to(library.root)
        catalogue = read_catalogue(write_example(tmp_path / "objects"))
        build_catalogue(catalogue, default_config(), progress=False)
        own = tmp_path / "lab"
        generate_dataset(own, catalogue_config(catalogue_record(catalogue), ("lab",), 4), progress=False)
        with_own = dataclasses.replace(config, own_datasets=(own,))
        summary = pipeline.run_pipeline(with_own, first_run.out, specs=specs, library=library, command=["pytest"])
        with pytest.raises(ConfigError, match="is no dataset of your own catalogue"):
            pipeline.run_pipeline(
                dataclasses.replace(config, own_datasets=(config.dataset,)), tmp_path / "x", specs=specs
            )
    assert summary.own_results == [first_run.out / "lab.results.json"] and not (tmp_path / "x").exists()
    scored = results.read_results(summary.own_results[0])
    assert sorted(e["key"] for e in scored["evaluations"]) == sorted(specs)
    assert all(len(e["subsets"]["lab"]["scenes"]) == 4 for e in scored["evaluations"])
    assert "lab (your objects)" in summary.own_results[0].with_suffix(".md").read_text()
