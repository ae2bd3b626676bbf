"""notebooks/01_grounding_logits.ipynb runs end to end on a tiny dataset, backbone and run, in the default suite:
the smoke dataset's `seen` split (8 scenes), a tiny CLIP and 100 training steps."""

from pathlib import Path

import pytest
from notebook_run import executed_outputs, printed
from tiny_clip import build_tiny_clip

NOTEBOOK = Path(__file__).resolve().parents[1] / "notebooks" / "01_grounding_logits.ipynb"


# Slow: the default suite's 15 min budget on 2 cores (docs/performance.md, session 12); the results notebook,
# executed on the smoke results, stays in it
@pytest.mark.slow
def test_grounding_notebook_executes(tmp_path, smoke_dataset, monkeypatch):
    from ocplace.methods.ours.recipe import smoke_config
    from ocplace.methods.ours.train import train_ours as train
    from ocplace.models.backbone import load_clip_backbone
    from ocplace.models.features import featurize, load_features
    from ocplace.sim.dataset.identity import dataset_hash
    from ocplace.sim.dataset.loader import iter_examples
    from ocplace.train.schedule import rescheduled

    dataset, features_path, run = smoke_dataset, tmp_path / "seen.safetensors", tmp_path / "run"
    backbone = load_clip_backbone(str(build_tiny_clip(tmp_path / "clip")), max_batch=8)
    featurize(
        iter_examples(dataset, "seen"),
        backbone,
        features_path,
        dataset_hash=dataset_hash(dataset, "seen"),
        progress=False,
    )
    train(load_features(features_path), run, rescheduled(smoke_config(), steps=100), progress=False)

    for name, value in {
        "OCPLACE_DATASET": dataset,
        "OCPLACE_SPLIT": "seen",
        "OCPLACE_FEATURES": features_path,
        "OCPLACE_RUN": run,
        "OCPLACE_OUTCOMES": recorded_outcomes(dataset, tmp_path / "outcomes.jsonl.gz"),
    }.items():
        monkeypatch.setenv(name, str(value))
    outputs = executed_outputs(NOTEBOOK, tmp_path)
    text = printed(outputs)
    assert "with adapters: GroundingAccuracy" in text and "scenes of 'seen'" in text
    assert sum(o.output_type == "display_data" for o in outputs) >= 6  # P, confusion, bars, sweeps, ranks, calibration
    assert "references of 'ours' with a true token, from outcomes.jsonl.gz" in text
    # The sweep's zero-shot point is the backbone alone, as w/o Adapter grounds, on the same features.
    from ocplace.models.grounding import GroundingModel
    from ocplace.models.trained_adapters import load_adapters
    from ocplace.train.metrics import evaluate_features

    features, logit_scale = load_features(features_path), load_adapters(run).model.logit_scale
    zero_shot = evaluate_features(GroundingModel.zero_shot(features.dim, logit_scale), features).tuple_accuracy
    assert f"zero-shot point (both ratios 0): {zero_shot:.4f}" in text


def recorded_outcomes(dataset: Path, path: Path) -> Path:
    """An outcomes file as an evaluation writes it, of Ours grounding every reference of the smoke test subsets
    (the true token most probable on every other scene)."""
    import numpy as np

    from ocplace import serial
    from ocplace.eval.api import MethodOutput
    from ocplace.eval.harness import score_scene
    from ocplace.eval.results import write_outcomes
    from ocplace.sim.dataset.job import scene_dirs
    from ocplace.sim.dataset.records import read_scene
    from ocplace.vocabulary import TEST_SUBSETS

    subsets = {}
    for subset in TEST_SUBSETS:
        scenes = []
        for index, folder in enumerate(scene_dirs(dataset, subset)):
            record = read_scene(folder)
            rows = np.full((len(record.tuples), len(record.boxes) + 1), 0.1)
            for row, item in zip(rows, record.tuples):
                row[(item.token_index + index % 2) % row.size] = 0.8
            parsed = tuple((item.reference_name, item.relation) for item in record.tuples)
            output = MethodOutput(
                np.zeros(2), None, parsed, tuple(rows.argmax(1).tolist()), probabilities=rows.tolist()
            )
            scenes.append(serial.to_dict(score_scene(record, output)))
        subsets[subset] = {"scenes": scenes}
    return write_outcomes(
        path, {"evaluations": [{"key": "ours", "method": "ours", "fraction": 1.0, "subsets": subsets}]}
    )
