"""The bare spec `offline` (the default recipe's backbone, documented as every `--backbone` default) works at
every entry point that takes a backbone: one loader, `models.backbone.load_backbone`, reads it everywhere.

`default_offline_backbone` (conftest.py) puts the tiny backbone where the default recipe's backbone is
saved, in a cache of the test's own, so `offline` finds it in this process and in the tasks it starts.
"""

import json

import pytest

from ocplace.cli import main
from ocplace.errors import BackboneUnavailable
from ocplace.models.backbone import load_backbone


def test_a_bare_kind_is_the_kind_with_an_empty_argument(default_offline_backbone, tiny_backbone_spec):
    assert load_backbone("offline").fingerprint == load_backbone("offline:").fingerprint
    assert load_backbone("offline").fingerprint == load_backbone(tiny_backbone_spec).fingerprint


def test_a_bare_kind_that_is_not_built_says_how_to_build_it(tmp_path, monkeypatch):
    monkeypatch.setenv("OCPLACE_CACHE", str(tmp_path))
    with pytest.raises(BackboneUnavailable, match="ocplace backbone pretrain"):
        load_backbone("offline")


def test_featurize(default_offline_backbone, smoke_dataset, tmp_path):
    out = tmp_path / "seen.safetensors"
    command = [
        "featurize",
        "--dataset",
        str(smoke_dataset),
        "--split",
        "seen",
        "--backbone",
        "offline",
        "--out",
        str(out),
    ]
    assert main(command) == 0 and out.is_file()


def test_backbone_eval_by_default(default_offline_backbone, smoke_dataset, tmp_path):
    out = tmp_path / "eval.json"
    command = ["backbone", "eval", "--data", str(smoke_dataset), "--splits", "seen", "--limit", "2"]
    assert main([*command, "--no-random-init", "--out", str(out)]) == 0
    assert json.loads(out.read_text())["backbone"] == "offline"


def test_backbone_validate(default_offline_backbone, corpus, capsys):
    assert main(["backbone", "validate", "--backbone", "offline", "--scenes", "4"]) == 0
    assert "grounding top-1" in capsys.readouterr().out


def test_place_by_default(default_offline_backbone, smoke_dataset, tmp_path, capsys):
    out = tmp_path / "place.png"
    assert main(["place", "--dataset", str(smoke_dataset), "--id", "0", "--out", str(out)]) in (0, 2)
    assert "zero-shot grounding" in capsys.readouterr().out and out.is_file()


# Slow: the default suite's 15 min budget on 2 cores (docs/performance.md, session 12); placing and evaluating
# on the bare spec in this process stay in it (test_place_by_default, test_backbone_eval_by_default)
@pytest.mark.slow
def test_evaluate(default_offline_backbone, smoke_dataset, tmp_path):
    out = tmp_path / "results.json"
    options = ["--subsets", "seen", "--limit", "2", "--physical", "0", "--no-progress", "--workers", "1"]
    command = ["evaluate", "--dataset", str(smoke_dataset), "--methods", "no_adapter", "--backbone", "offline"]
    assert main([*command, *options, "--out", str(out)]) == 0
    [entry] = json.loads(out.read_text())["evaluations"]
    assert entry["description"]["backbone"]["spec"] == "offline"


@pytest.mark.slow  # ~30 s; `evaluate` above resolves the bare spec in its tasks the same way (both in make test-all)
def test_reproduce(default_offline_backbone, smoke_dataset, tmp_path):
    out = tmp_path / "out"
    command = ["reproduce", "--experiment", "smoke", "--out", str(out), "--dataset", str(smoke_dataset)]
    options = ["--methods", "no_adapter", "--set", "evaluation.subsets=seen", "--physical", "0", "--no-progress"]
    assert main([*command, "--backbone", "offline", *options, "--workers", "1"]) == 0
    results = json.loads((out / "results.json").read_text())
    assert results["pipeline"]["errors"] == [] and results["settings"]["backbone"] == "offline"
