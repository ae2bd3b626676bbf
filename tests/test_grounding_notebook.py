"""notebooks/01_grounding_logits.ipynb runs end to end on a tiny dataset, backbone and run, in the default suite:
the smoke dataset's `seen` split (8 scenes), a tiny CLIP and 100 training steps."""

from pathlib import Path

from notebook_run import executed_outputs, printed
from tiny_clip import build_tiny_clip

NOTEBOOK = Path(__file__).resolve().parents[1] / "notebooks" / "01_grounding_logits.ipynb"


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
    }.items():
        monkeypatch.setenv(name, str(value))
    outputs = executed_outputs(NOTEBOOK, tmp_path)
    text = printed(outputs)
    assert "with adapters: GroundingAccuracy" in text and "scenes of 'seen'" in text
    assert sum(o.output_type == "display_data" for o in outputs) >= 4  # P matrices, confusion, bars, sweeps
