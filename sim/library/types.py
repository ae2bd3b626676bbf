"""What a built object is: the record the scene code, the dataset and the models read."""

from __future__ import annotations

import dataclasses
from pathlib import Path

CORPUS_SPLIT = "corpus"  # arena-only objects of the pretraining corpus (`sim/corpus/`), never in the library


@dataclasses.dataclass(frozen=True)
class VisualPart:
    """A further visual mesh of a multi-material object, with its own texture or colour."""

    mesh: Path  # OBJ, with UVs when textured
    texture: Path | None  # PNG; None: `rgba` alone
    rgba: tuple[float, float, float, float]  # the colour, or the tint of the texture


@dataclasses.dataclass(frozen=True)
class ObjectAsset:
    """One processed object in the library cache.

    Meshes are in metres, in the object frame: base on z = 0, AABB centred on x = y = 0,
    +z up in the object's stable resting pose.
    """

    name: str  # stable identifier, e.g. "alphabet_soup"
    human_name: str  # what instructions call it, e.g. "alphabet soup can"
    synonyms: tuple[str, ...]
    category: str  # the category noun people use, e.g. "can", "bowl", "teddy bear"
    split: str  # "seen", "unseen" or "unseen_cat" (vocabulary.LIBRARY_SPLITS)
    source: str  # e.g. "libero:stable_hope_objects", "pybullet_data", "gso:/path"
    licence: str
    directory: Path  # cache folder holding every file below
    visual_mesh: Path  # textured OBJ with UVs, <= 20k faces
    texture: Path | None  # PNG, <= 1024 px; None for an untextured object
    rgba: tuple[float, float, float, float]  # base colour, used when texture is None
    hulls: tuple[Path, ...]  # convex collision pieces (OBJ), at most 32
    mjcf: Path  # standalone MuJoCo model of the object
    urdf: Path  # PyBullet model of the same meshes
    extents: tuple[float, float, float]  # AABB size (x, y, z) in metres
    mass: float  # kg
    # Further visual meshes, one per further material (the pretraining corpus' models); library
    # objects have one material and none.
    parts: tuple[VisualPart, ...] = ()

    @property
    def visual_parts(self) -> tuple[VisualPart, ...]:
        """Every visual mesh with its material: the main one, then `parts`."""
        return (VisualPart(self.visual_mesh, self.texture, self.rgba), *self.parts)
