"""A user's own CLIP weights through every path (issue 58): `reproduce` with a `clip:` backbone writes its results
and a policy folder that refers to the checkpoint; the folder loads, places and evaluates; `export` finds the
checkpoint from the run's record; missing files and a moved or different checkpoint are typed errors.

A tiny random CLIP checkpoint (tests/tiny_clip.py), written as `save_pretrained` writes real ones, stands in.
"""

import dataclasses
import json
import shutil

import jax
import pytest
from tiny_clip import build_tiny_clip

from ocplace import configs
from ocplace.cli import main
from ocplace.errors import BackboneError, BackboneUnavailable, EvaluationError, PolicyFolderError
from ocplace.eval import results
from ocplace.experiments import pipeline
from ocplace.methods.contract import done_record
from ocplace.methods.policy_method import scene_input
from ocplace.methods.registry import method_specs
from ocplace.methods.run_backbone import runs_backbone, trained_backbone
from ocplace.models.backbone import load_clip_backbone
from ocplace.models.placement.sampler import SamplerConfig
from ocplace.models.policy import PlacementPolicy
from ocplace.models.policy_folder import CONFIG_FILE
from ocplace.sim.dataset.job import listed_scenes

SAMPLER = SamplerConfig(num_samples=64)


@pytest.fixture(scope="module")
def clip_dir(tmp_path_factory, tokenizer_dir):
    return build_tiny_clip(tmp_path_factory.mktemp("clip"), seed=3, tokenizer_dir=tokenizer_dir)


@pytest.fixture(scope="module")
def clip_reproduce(clip_dir, smoke_dataset, library, tmp_path_factory):
    """`reproduce --backbone clip:DIR` at smoke size, Ours only, in a cache of its own (the run's folder)."""
    smoke = configs.get("smoke")
    evaluation = dataclasses.replace(smoke.evaluation, methods=("ours",), fractions=(1.0,), fraction_methods=())
    experiment = dataclasses.replace(
        smoke, dataset=dataclasses.replace(smoke.dataset, physical_scenes=0), evaluation=evaluation
    )
    config = pipeline.PipelineConfig(experiment, backbone=f"clip:{clip_dir}", dataset=smoke_dataset, progress=False)
    out = tmp_path_factory.mktemp("clip_reproduce")
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("OCPLACE_CACHE", str(tmp_path_factory.mktemp("clip_cache")))
        summary = pipeline.run_pipeline(
            config, out, specs={"ours": method_specs()["ours"]}, library=library, command=["pytest"]
        )
    return summary


def test_reproduce_with_a_clip_backbone_writes_results_and_a_policy_folder(clip_reproduce, clip_dir):
    assert clip_reproduce.errors == []
    saved = results.read_results(clip_reproduce.results_path)
    [ours] = saved["evaluations"]
    assert ours["description"]["backbone"]["spec"] == f"clip:{clip_dir}"
    assert ours["subsets"]["seen"]["aggregate"]["overall"]["scenes"] == 8
    folder = clip_reproduce.out / pipeline.POLICY_FOLDER
    document = json.loads((folder / CONFIG_FILE).read_text())
    backbone = load_clip_backbone(str(clip_dir))
    assert document["backbone"] == {
        "kind": "clip",
        "checkpoint": str(clip_dir.resolve()),
        "fingerprint": backbone.fingerprint,
    }
    card = (folder / "README.md").read_text()
    assert "| Ours |" in card and "CLIP checkpoint, not copied" in card


def test_a_clip_policy_folder_places_as_its_run(clip_reproduce, clip_dir, smoke_dataset, tmp_path):
    run_dir = clip_reproduce.out / "runs" / "ours" / "fraction-1.00"
    scenes = [scene_input(scene.read()) for scene in listed_scenes(smoke_dataset, "unseen_obj")]
    from_run = PlacementPolicy.from_run(load_clip_backbone(str(clip_dir)), run_dir, sampler=SAMPLER)
    copied = shutil.copytree(clip_reproduce.out / pipeline.POLICY_FOLDER, tmp_path / "policy")
    loaded = PlacementPolicy.from_pretrained(copied, sampler=SAMPLER)
    for a, b in zip(from_run.place_many(scenes, jax.random.key(1)), loaded.place_many(scenes, jax.random.key(1))):
        assert a.failure == b.failure and a.tokens == b.tokens
    # The checkpoint moved: the folder says where it looked; told where it is, it loads.
    moved = shutil.move(str(clip_dir), str(tmp_path / "moved_clip"))
    try:
        with pytest.raises(PolicyFolderError, match="pass where it is now"):
            PlacementPolicy.from_pretrained(copied)
        assert PlacementPolicy.from_pretrained(copied, checkpoint=str(moved)).backbone.fingerprint == (
            from_run.backbone.fingerprint
        )
    finally:
        shutil.move(moved, str(clip_dir))


def test_a_different_checkpoint_is_refused_by_fingerprint(clip_reproduce, tmp_path, tokenizer_dir):
    other = build_tiny_clip(tmp_path / "other", seed=4, tokenizer_dir=tokenizer_dir)
    with pytest.raises(PolicyFolderError, match="is not the one .* was trained on"):
        PlacementPolicy.from_pretrained(clip_reproduce.out / pipeline.POLICY_FOLDER, checkpoint=str(other))


def test_cli_exports_places_and_evaluates_a_clip_run(clip_reproduce, clip_dir, smoke_dataset, tmp_path, capsys):
    run_dir = clip_reproduce.out / "runs" / "ours" / "fraction-1.00"
    folder = tmp_path / "exported"
    assert main(["export", "--run", str(run_dir), "--out", str(folder)]) == 0  # the backbone from the run's record
    assert json.loads((folder / CONFIG_FILE).read_text())["backbone"]["checkpoint"] == str(clip_dir.resolve())
    scene = listed_scenes(smoke_dataset, "seen")[0].name
    place = ["place", "--policy", str(folder), "--dataset", str(smoke_dataset), "--id", scene, "--samples", "64"]
    assert main([*place, "--out", str(tmp_path / "p.png")]) in (0, 2)  # placed, or refused with the typed error
    out = tmp_path / "r.json"
    evaluate = ["evaluate", "--policy", str(folder), "--dataset", str(smoke_dataset), "--out", str(out)]
    assert main([*evaluate, "--subsets", "seen", "--num-samples", "64", "--no-progress"]) == 0
    [entry] = results.read_results(out)["evaluations"]
    assert entry["subsets"]["seen"]["aggregate"]["overall"]["scenes"] == 8
    capsys.readouterr()


# Each case: the files taken away, and the words the error must say.
INCOMPLETE = {
    "config": (("config.json",), "the model's config"),
    "weights": (("flax_model.msgpack", "model.safetensors"), "the weights"),
    "tokenizer": (("tokenizer.json", "vocab.json"), "the tokenizer"),
    "merges": (("tokenizer.json", "merges.txt"), "merges.txt"),
    "preprocessor": (("preprocessor_config.json",), "the image preprocessing"),
}


@pytest.mark.parametrize("case", INCOMPLETE)
def test_an_incomplete_clip_folder_names_what_it_lacks(clip_dir, tmp_path, case):
    folder = shutil.copytree(clip_dir, tmp_path / "clip")
    removed, said = INCOMPLETE[case]
    for name in removed:
        (folder / name).unlink(missing_ok=True)
    with pytest.raises(BackboneError, match="not a complete CLIP checkpoint") as error:
        load_clip_backbone(str(folder))
    assert said in str(error.value) and "CLIPProcessor.from_pretrained(ID).save_pretrained(DIR)" in str(error.value)


# Slow: the default suite's 15 min budget on 2 cores (docs/performance.md, session 12); the CLIP reproduce, export,
# place and evaluate stay in it
@pytest.mark.slow
def test_evaluate_runs_from_scores_every_row_on_the_backbone_the_runs_were_trained_on(
    clip_reproduce, clip_dir, smoke_dataset, tmp_path, capsys
):
    out = tmp_path / "runs.json"
    command = ["evaluate", "--runs-from", str(clip_reproduce.out), "--methods", "ours,no_adapter"]
    options = ["--dataset", str(smoke_dataset), "--subsets", "seen", "--num-samples", "64", "--no-progress"]
    assert main([*command, *options, "--out", str(out)]) == 0  # no --backbone: the runs' own, not `offline`
    assert f"backbone: clip:{clip_dir} (the one the runs were trained on)" in capsys.readouterr().out
    specs = {e["method"]: e["description"]["backbone"]["spec"] for e in results.read_results(out)["evaluations"]}
    assert specs == {"ours": f"clip:{clip_dir}", "no_adapter": f"clip:{clip_dir}"}


def test_runs_on_different_backbones_are_not_scored_together(tmp_path):
    runs = []
    for name in ("a", "b"):
        backbone, run_dir = tmp_path / f"backbone_{name}", tmp_path / "runs" / name
        backbone.mkdir()
        run_dir.mkdir(parents=True)
        done_record(run_dir).write_text(json.dumps({"context": {"backbone": f"offline:{backbone}"}}))
        runs.append(run_dir)
    assert trained_backbone(runs[0]) == f"offline:{tmp_path / 'backbone_a'}"
    with pytest.raises(EvaluationError, match="trained on different backbones"):
        runs_backbone(runs)
    shutil.rmtree(tmp_path / "backbone_a")  # recorded, but not here, and no fingerprint to find another by
    with pytest.raises(BackboneUnavailable, match="no backbone fingerprint to find its backbone by .`offline:"):
        trained_backbone(runs[0])


def test_a_clip_folders_card_names_no_hub_model_for_a_local_checkpoint(clip_reproduce):
    from huggingface_hub import ModelCard

    card = ModelCard((clip_reproduce.out / pipeline.POLICY_FOLDER / "README.md").read_text())
    assert card.data.library_name == "ocplace" and card.data.base_model is None


def test_a_folder_that_names_a_hub_id_never_downloads_it(clip_reproduce, tmp_path, monkeypatch):
    """A policy folder is data: the hub id it names is taken from the Hugging Face cache or refused, never fetched."""
    import socket

    def no_network(*args, **kwargs):
        raise AssertionError("a policy folder reached for the network")

    monkeypatch.setattr(socket, "create_connection", no_network)
    folder = shutil.copytree(clip_reproduce.out / pipeline.POLICY_FOLDER, tmp_path / "policy")
    document = json.loads((folder / CONFIG_FILE).read_text())
    document["backbone"]["checkpoint"] = "someone/a-clip-nobody-cached"
    (folder / CONFIG_FILE).write_text(json.dumps(document))
    with pytest.raises(PolicyFolderError, match="never downloaded on its own"):
        PlacementPolicy.from_pretrained(folder)
