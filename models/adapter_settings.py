"""What a training recipe sets of its CLIP-Adapters (`AdapterSettings`), without JAX: the width is the
backbone's, known when the training reads its features (`AdapterSettings.at`)."""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

from ocplace.serial import bounded

if TYPE_CHECKING:
    from ocplace.models.adapters import AdapterConfig


@dataclasses.dataclass(frozen=True)
class AdapterSettings:
    reduction: int = bounded(4, 1, 8192, help="the adapter's hidden width is D / reduction")
    residual_ratio: float = bounded(
        0.2, 0.0, 1.0, help="the adapter's weight in the blend: the visual tower's, and the text's unless set"
    )
    text_ratio: float | None = bounded(
        None, 0.0, 1.0, help="the text adapter's own weight in the blend; none: residual_ratio"
    )
    normalise: bool = dataclasses.field(
        default=False, metadata={"help": "scale A(x) to the norm of x before the blend (models/adapters.py)"}
    )

    def at(self, dim: int) -> AdapterConfig:
        """The `AdapterConfig` of these adapters on a backbone `dim` wide."""
        from ocplace.models.adapters import AdapterConfig  # Flax behind it: this module stays light

        return AdapterConfig(dim, **dataclasses.asdict(self))

    def problems(self) -> list[str]:
        problems = []
        if self.reduction < 1:
            problems.append(f"reduction must be at least 1 (hidden width = D / reduction), got {self.reduction}")
        for name in ("residual_ratio", "text_ratio"):
            value = getattr(self, name)
            if value is not None and not 0.0 <= value <= 1.0:
                problems.append(f"{name} must be in [0, 1], got {value}")
        return problems
