"""Placement: the truncated-Gaussian density over the table and its exact sampler (JAX)."""

from ocplace.models.placement.place import explain_empty, place
from ocplace.models.placement.sampler import (
    PlacementResult,
    SamplerConfig,
    default_config,
    sample_placements,
)

__all__ = [
    "PlacementResult",
    "SamplerConfig",
    "default_config",
    "explain_empty",
    "place",
    "sample_placements",
]
