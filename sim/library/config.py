"""Settings of an object library build."""

from __future__ import annotations

import dataclasses


@dataclasses.dataclass(frozen=True)
class CoacdSettings:
    """Convex decomposition settings (see coacd.run_coacd).

    Defaults were measured to keep concave objects (bowls, mugs, baskets) within about 10 s on
    one core with hulls that follow their cavities: see docs/library.md.
    """

    threshold: float = 0.15  # concavity stop criterion; lower = more, tighter pieces
    max_convex_hull: int = 32  # pieces beyond this are merged greedily (see processing.merge_hulls)
    preprocess_resolution: int = 30  # only for inputs that are not closed manifolds
    resolution: int = 500
    mcts_nodes: int = 10
    mcts_iterations: int = 20
    mcts_max_depth: int = 1
    max_ch_vertex: int = 64  # vertices per hull, keeps MuJoCo and PyBullet collision cheap
    seed: int = 0


@dataclasses.dataclass(frozen=True)
class LibraryConfig:
    """What to build and how.

    `objects` selects names from the metadata (None = every object); `gso_dirs` adds every
    object found in those Google-Scanned-Objects-layout directories.
    """

    coacd: CoacdSettings = CoacdSettings()
    max_faces: int = 20_000  # visual mesh
    collision_faces: int = 2_000  # mesh handed to coacd, simplified first for speed
    convex_ratio: float = 0.8  # volume / hull volume above which one convex hull is the collision
    texture_px: int = 1024
    density: float = 300.0  # kg/m^3, applied to the hull volume
    objects: tuple[str, ...] | None = None
    gso_dirs: tuple[str, ...] = ()

    def processing_settings(self) -> dict:
        """Everything that changes an object's processed files (part of its cache key)."""
        return {
            "coacd": dataclasses.asdict(self.coacd),
            "max_faces": self.max_faces,
            "collision_faces": self.collision_faces,
            "convex_ratio": self.convex_ratio,
            "texture_px": self.texture_px,
            "density": self.density,
        }


SMOKE_OBJECTS = ("alphabet_soup", "cookies", "white_bowl", "rubber_duck", "lego_brick")


def default_config() -> LibraryConfig:
    return LibraryConfig()


def smoke_config() -> LibraryConfig:
    """A handful of objects (both mesh formats, textured and plain) with fast coacd, for tests."""
    return LibraryConfig(
        coacd=CoacdSettings(
            threshold=0.3,
            max_convex_hull=8,
            preprocess_resolution=20,
            resolution=300,
            mcts_nodes=5,
            mcts_iterations=10,
            mcts_max_depth=1,
        ),
        max_faces=5_000,
        collision_faces=1_000,
        texture_px=256,
        objects=SMOKE_OBJECTS,
    )
