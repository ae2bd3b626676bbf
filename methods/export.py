"""A trained Ours run as a policy folder (`ocplace export`; `reproduce` writes OUT/policy for its Ours run).

The folder's format is `models/policy_folder.py`'s, its card `models/policy_card.py`'s; this module finds the
run's backbone, writes the folder with the run in its card and, once an evaluation is at hand, the card's Table I
row.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from ocplace.errors import PolicyFolderError
from ocplace.models.policy_card import NOT_EVALUATED, card_text
from ocplace.models.policy_folder import CARD_FILE, export_policy, read_policy_config

if TYPE_CHECKING:
    from ocplace.models.policy import PlacementPolicy
    from ocplace.models.trained_adapters import TrainedAdapters


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

    run, folder = Path(run_dir).resolve(), Path(out).resolve()
    if folder == run or run in folder.parents or folder in run.parents:
        raise PolicyFolderError(
            f"the policy folder {out} would be written into (or over) the run {run_dir} it is made from: "
            "choose an --out outside the run"
        )
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
    card = card_text(Path(out), source, NOT_EVALUATED)
    return export_policy(policy, out, parser=parser, card=card, source=source)


def write_table_row(folder: str | Path, row: str) -> None:
    """The model card of `folder` with its Table I row (markdown)."""
    from ocplace.paths import write_text_atomic

    folder = Path(folder)
    write_text_atomic(folder / CARD_FILE, card_text(folder, read_policy_config(folder)["source"], row))
