"""What a policy folder's `config.json` may hold, checked before any weights are read or any JAX runs.

A folder travels (a lab downloads one), so its text is untrusted input: every field is typed and bounded by the
dataclasses it rebuilds (their `bounded` fields and `problems()`, `ocplace.serial.text_problems`), the sections the
loader reads must all be there, and a folder never chooses a network service by itself (its parser may not be the
LLM unless the caller names it). Every problem is listed in one PolicyFolderError.
"""

from __future__ import annotations

import dataclasses
from typing import Literal

from ocplace import serial
from ocplace.models.adapters import AdapterConfig
from ocplace.models.backbone import PromptConfig
from ocplace.models.detection import DetectorConfig
from ocplace.models.inference_settings import Decision
from ocplace.models.offline_config import OfflineConfig
from ocplace.models.parsing.config import PARSER_NAMES
from ocplace.models.placement.sampler import SamplerConfig
from ocplace.serial import bounded
from ocplace.sim.dataset.loader import CROP_SIZE, MAX_BOXES
from ocplace.vocabulary import GATE_THRESHOLD, MAX_PARSED_TUPLES

NETWORK_PARSERS = ("llm",)  # parsers that send the instruction to a service: never picked by a folder
_FINGERPRINT = 64  # hex digits of a backbone fingerprint


@dataclasses.dataclass(frozen=True)
class PolicySection:
    """`config.json`'s `policy`: the PlacementPolicy fields besides the models."""

    crop_size: int = bounded(CROP_SIZE, 16, 1024)
    decision: Decision = Decision()  # a folder written before the joint decision lacks it: argmax
    detector: DetectorConfig = DetectorConfig()
    max_tuples: int = bounded(MAX_PARSED_TUPLES, 1, MAX_PARSED_TUPLES)
    min_boxes: int = bounded(MAX_BOXES, 1, 256)
    parser: str = "offline"
    sampler: SamplerConfig = SamplerConfig()
    threshold: float = bounded(GATE_THRESHOLD, 0.0, 1.0)

    def problems(self) -> list[str]:
        found = [f"decision: {problem}" for problem in self.decision.problems(self.max_tuples)]
        if self.parser not in PARSER_NAMES:
            found.append(f"parser {self.parser!r} is none of {', '.join(PARSER_NAMES)}")
        return found


@dataclasses.dataclass(frozen=True)
class AdaptersSection:
    """`config.json`'s `adapters`: the grounding model's configuration besides its weights."""

    config: AdapterConfig = AdapterConfig()
    logit_scale: float = bounded(100.0, 1e-3, 1000.0)
    prompt: PromptConfig = PromptConfig()


@dataclasses.dataclass(frozen=True)
class TextTower:
    package: str = ""
    sha256: str = ""


@dataclasses.dataclass(frozen=True)
class BackboneSection:
    """`config.json`'s `backbone`: an offline backbone held in the folder, or a CLIP checkpoint it refers to."""

    kind: Literal["offline", "clip"] = "offline"
    fingerprint: str = ""
    model: OfflineConfig | None = None  # offline
    text_tower: TextTower | None = None  # offline
    checkpoint: str | None = None  # clip: a folder or a hub id

    def problems(self) -> list[str]:
        found = []
        if len(self.fingerprint) != _FINGERPRINT or any(c not in "0123456789abcdef" for c in self.fingerprint):
            found.append(f"fingerprint must be {_FINGERPRINT} hex digits, got {self.fingerprint[:80]!r}")
        needed = ("model", "text_tower") if self.kind == "offline" else ("checkpoint",)
        found += [f"a backbone of kind {self.kind!r} needs {name}" for name in needed if getattr(self, name) is None]
        return found


# The sections the loader reads, and each one's fields that must be there (the rest keep their defaults).
SECTIONS = {"policy": PolicySection, "adapters": AdaptersSection, "backbone": BackboneSection}
REQUIRED = {
    "policy": ("crop_size", "detector", "max_tuples", "min_boxes", "parser", "sampler", "threshold"),
    "adapters": ("config", "logit_scale", "prompt"),
    "backbone": ("kind", "fingerprint"),
}


def folder_problems(document: dict, parser_given: bool) -> list[str]:
    """Every problem of a policy folder's `config.json` (decoded), each naming its field; `parser_given`: the
    caller chose the parser, so the folder's is not used."""
    found = []
    files = document.get("files")
    if not isinstance(files, dict) or not isinstance(files.get("model.safetensors"), str):
        found.append("files: the sha256 of model.safetensors is needed")
    for name, section in SECTIONS.items():
        data = document.get(name)
        if not isinstance(data, dict):
            found.append(f"{name}: missing, or not an object")
            continue
        found += [f"{name}.{field}: missing" for field in REQUIRED[name] if field not in data]
        found += serial.text_problems(section, data, name)
    policy = document.get("policy")
    parser = policy.get("parser") if isinstance(policy, dict) else None
    if parser in NETWORK_PARSERS and not parser_given:
        found.append(
            f"policy.parser: the folder asks for the {parser!r} parser, which sends each instruction to a network "
            f"service; a folder never chooses one: pass the parser yourself (`--parser {parser}`, or "
            f"`parser={parser!r}` in code) to allow it, or any other to use that"
        )
    return found
