"""A policy folder as a Table I row: `ocplace evaluate --policy DIR` (beside `--policy MODULE:CALLABLE`).

The folder brings its backbone, adapters and settings; the evaluation sets what it sets for every method
(parser, samples per scene, refusal threshold). Its method name is `folder:<absolute path>`, which is how
`--rerun` finds it again; a folder holds no code, so a rerun loads it without `--trust-policy`.
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path
from typing import Any

from ocplace.methods.contract import LoadContext, MethodSpec
from ocplace.methods.policy_method import PolicyMethod, describe_policy

FOLDER_PREFIX = "folder:"


def is_folder_reference(reference: str) -> bool:
    """Whether `--policy REFERENCE` (or a results file's method name) names a policy folder."""
    from ocplace.models.policy_folder import CONFIG_FILE

    return reference.startswith(FOLDER_PREFIX) or (Path(reference) / CONFIG_FILE).is_file()


def folder_spec(reference: str, label: str | None = None) -> MethodSpec[Any]:
    """The spec of a policy folder; its config is read here, so that a bad folder fails before any work."""
    from ocplace.models.policy_folder import read_policy_config

    folder = Path(reference.removeprefix(FOLDER_PREFIX)).resolve()
    read_policy_config(folder)
    name = f"{FOLDER_PREFIX}{folder}"
    return MethodSpec(name=name, label=label or folder.name, load=functools.partial(load_folder, str(folder)))


def load_folder(folder: str, context: LoadContext) -> FolderMethod:
    from ocplace.models.policy import PlacementPolicy

    policy = PlacementPolicy.from_pretrained(folder, parser=context.parser)
    sampler = dataclasses.replace(policy.sampler, num_samples=context.num_samples)
    policy = dataclasses.replace(policy, sampler=sampler, threshold=context.threshold)
    return FolderMethod(f"{FOLDER_PREFIX}{folder}", policy, f"{FOLDER_PREFIX}{folder}", None)


@dataclasses.dataclass
class FolderMethod(PolicyMethod):
    """`PolicyMethod` whose adapters come from a policy folder's `model.safetensors`."""

    def describe(self) -> dict[str, Any]:
        from ocplace.models.policy_folder import MODEL_FILE, read_policy_config

        folder = self.name.removeprefix(FOLDER_PREFIX)
        described = describe_policy(self.policy, self.name, self.backbone_spec, None)
        described["adapters"] = {"policy_folder": folder, "sha256": read_policy_config(folder)["files"][MODEL_FILE]}
        described["grounding"]["zero_shot"] = False
        return described
