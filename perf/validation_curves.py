"""Validation curves of Ours' adapters: grounding on the dev splits and the corpus' held-out categories along one
training run, never a test subset.

Two recipes are trained on the training split's features without the seen colour variants (as rule A's selection
runs, `perf/adapter_selection.py`): Ours (rule A's adapters, `methods.ours.recipe.default_config()`) and the paper's
adapters (`paper_config()`), each for its full budget with a checkpoint every `--every` steps. Every checkpoint is
then scored as blended by its recipe: `dev_seen` and `dev_colour` object tuples (the colour variants are new
instances to these runs) and reach (the held-out corpus categories). Step 0 is the backbone alone (w/o Adapter).
The curves show what the budget does to each recipe; nothing is chosen on them.

Usage: `python perf/validation_curves.py --dataset DATA --dev DEV --backbone SPEC --out curves.json --figure
curves.png` (DATA holds the training split, DEV the dev splits).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

from adapter_selection import selection_features
from selection_scores import standard_error

import ocplace  # noqa: F401  (sets the headless OpenGL default before MuJoCo loads)

SPLITS = ("dev_seen", "dev_colour", "reach")


def recipes(steps: int | None) -> dict:
    """Ours and the paper's adapters, at their budget or `steps` (a shorter look)."""
    from ocplace.methods.ours import recipe as config
    from ocplace.train.schedule import rescheduled

    chosen = {"ours": config.default_config(), "ours_paper": config.paper_config()}
    return {name: rescheduled(recipe, steps=steps or recipe.schedule.steps) for name, recipe in chosen.items()}


def scores(model, splits: dict) -> dict:
    """`{split: top-1, split_tuples: count}` of `model` on every split."""
    from ocplace.train.metrics import evaluate_features

    row = {}
    for name, features in splits.items():
        accuracy = evaluate_features(model, features)
        row[name], row[f"{name}_tuples"] = accuracy.tuple_accuracy, accuracy.num_tuples
    return row


def curve(train, splits: dict, recipe, run_dir: Path, every: int) -> list[dict]:
    """One row per checkpoint of `recipe` trained on `train`, `{"step", split scores...}`, after the backbone's own
    (step 0: the adapters blended at ratio 0 on both towers)."""
    from ocplace.methods.ours.train import init_state, train_ours
    from ocplace.models.grounding import GroundingModel
    from ocplace.train import checkpoints, optim
    from ocplace.train.schedule import rescheduled

    keep = recipe.schedule.steps // every
    recipe = dataclasses.replace(rescheduled(recipe, checkpoint_every=every, keep_checkpoints=keep), eval_every=every)
    trained = train_ours(train, run_dir, recipe, progress=False).model
    adapter_config = recipe.adapters.at(train.dim)
    template = init_state(adapter_config, optim.make(recipe.schedule), 0)
    rows = [{"step": 0, **scores(trained.with_ratios(0.0, 0.0), splits)}]
    for path in checkpoints.list_checkpoints(run_dir):
        state, step, _ = checkpoints.load_checkpoint(path, template)
        model = GroundingModel(adapter_config, state[0], trained.logit_scale)
        rows.append({"step": step, **scores(model, splits)})
        print(run_dir.name, json.dumps(rows[-1]))
    return rows


def draw(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(1, len(SPLITS), figsize=(4 * len(SPLITS), 3.2), sharex=True)
    for axis, split in zip(axes, SPLITS, strict=True):
        zero_shot = result["curves"]["ours"][0][split]
        axis.axhline(100 * zero_shot, color="grey", linestyle=":", label="w/o Adapter (step 0)")
        for name, rows in result["curves"].items():
            steps = [row["step"] / 1000 for row in rows]
            values = [100 * row[split] for row in rows]
            errors = [100 * standard_error(row[split], row[f"{split}_tuples"]) for row in rows]
            axis.errorbar(steps, values, yerr=errors, marker="o", markersize=3, capsize=2, label=name)
        axis.set_title(split)
        axis.set_xlabel("training step (thousands)")
        axis.grid(alpha=0.3)
    axes[0].set_ylabel("grounding top-1, object tuples (%)")
    axes[-1].legend(fontsize=8)
    figure.tight_layout()
    figure.savefig(path, dpi=120)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", type=Path, required=True, help="dataset folder holding the training split")
    parser.add_argument("--dev", type=Path, required=True, help="dataset folder holding dev_seen and dev_colour")
    parser.add_argument("--backbone", default="offline")
    parser.add_argument("--every", type=int, default=10_000, help="steps between scored checkpoints")
    parser.add_argument("--steps", type=int, default=None, help="train this many steps (default: each budget)")
    parser.add_argument("--work", type=Path, default=Path("out/validation_curves"))
    parser.add_argument("--out", type=Path, default=Path("validation_curves.json"))
    parser.add_argument("--figure", type=Path, default=Path("validation_curves.png"))
    args = parser.parse_args()

    train, splits = selection_features(args.dataset, args.dev, args.backbone)
    curves = {
        name: curve(train, splits, recipe, args.work / name, args.every) for name, recipe in recipes(args.steps).items()
    }
    result = {
        "backbone": args.backbone,
        "fingerprint": train.info.backbone_fingerprint,
        "every": args.every,
        "curves": curves,
    }
    args.out.write_text(json.dumps(result, indent=1))
    draw(result, args.figure)
    print(f"wrote {args.out} and {args.figure}")


if __name__ == "__main__":
    main()
