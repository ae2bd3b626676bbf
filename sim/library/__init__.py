"""The object library: named, textured, convex-decomposed tabletop objects in the cache.

Build with `build_library(default_config())` (or `ocplace assets build`), read with
`load_library()`. See docs/library.md.
"""

from ocplace.sim.library.build import build_library
from ocplace.sim.library.config import CoacdSettings, LibraryConfig, default_config, smoke_config
from ocplace.sim.library.library import Library, TableTexture, load_library
from ocplace.sim.library.types import ObjectAsset

__all__ = [
    "CoacdSettings",
    "Library",
    "LibraryConfig",
    "ObjectAsset",
    "TableTexture",
    "build_library",
    "default_config",
    "load_library",
    "smoke_config",
]
