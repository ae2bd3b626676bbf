"""Scene specifications and the records a settled, rendered scene produces.

A `SceneSpec` is everything needed to rebuild a scene bit for bit: which objects are dropped, on
which table texture, which object the robot holds, and the seed of the drop poses.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ocplace.errors import SceneError
from ocplace.sim.library.library import colour_variants
from ocplace.vocabulary import COLOUR_VARIANTS, OBJECT_POOLS

NUM_SCENE_OBJECTS = 5


@dataclasses.dataclass(frozen=True)
class SceneSpec:
    objects: tuple[str, ...]  # library names, dropped in this order; object id = index + 1
    table_texture: str
    held_object: str  # not among `objects`
    seed: int  # seeds the drop poses

    def __post_init__(self):
        if len(set(self.objects)) != len(self.objects):
            raise SceneError(f"scene objects must be distinct, got {self.objects}")
        if self.held_object in self.objects:
            raise SceneError(f"the held object {self.held_object!r} cannot also be in the scene")


@dataclasses.dataclass(frozen=True)
class SceneObject:
    object_id: int  # 1..N, the value of its pixels in the segmentation image
    name: str
    position: np.ndarray  # (3,) world position of the object frame
    quaternion: np.ndarray  # (4,) w, x, y, z
    aabb: np.ndarray  # (2, 3) world-frame [[xmin, ymin, zmin], [xmax, ymax, zmax]]


@dataclasses.dataclass(frozen=True)
class RenderedScene:
    spec: SceneSpec
    objects: tuple[SceneObject, ...]
    rgb: np.ndarray  # (H, W, 3) uint8
    depth: np.ndarray  # (H, W) float32, planar depth in metres
    segmentation: np.ndarray  # (H, W) int32 object ids, 0 = table or background
    settle_steps: int


def sample_scene_spec(
    rng: np.random.Generator,
    object_pool: list[str],
    textures: list[str],
    held_pool: list[str] | None = None,
    num_objects: int = NUM_SCENE_OBJECTS,
) -> SceneSpec:
    """Draws distinct scene objects, a held object not among them, a texture and a drop seed."""
    needed = num_objects + 1 if held_pool is None else num_objects  # the held one from the same pool
    held_pool = object_pool if held_pool is None else held_pool
    if len(object_pool) < needed or not textures:
        raise SceneError(
            f"need at least {needed} objects and one texture, got {len(object_pool)} objects "
            f"and {len(textures)} textures; build the library with `ocplace assets build`"
        )
    chosen = rng.choice(len(object_pool), size=num_objects, replace=False)
    objects = tuple(object_pool[i] for i in chosen)
    held_candidates = [name for name in held_pool if name not in objects]
    if not held_candidates:
        raise SceneError("no held object left: every candidate is already in the scene")
    held = held_candidates[rng.integers(len(held_candidates))]
    texture = textures[rng.integers(len(textures))]
    return SceneSpec(objects, texture, held, int(rng.integers(2**31 - 1)))


def sample_mixed_spec(
    rng: np.random.Generator, own: list[str], distractors: list[str], textures: list[str]
) -> SceneSpec:
    """A scene of a user's subset mixed with benchmark distractors: the held object and as many scene objects as
    there are left (up to NUM_SCENE_OBJECTS) from `own`, the rest from `distractors`."""
    if len(own) < 3 or not textures:
        raise SceneError(f"a subset mixed with distractors needs at least 3 objects of its own, got {len(own)}")
    held = own[rng.integers(len(own))]
    rest = [name for name in own if name != held]
    mine = [rest[i] for i in rng.choice(len(rest), size=min(len(rest), NUM_SCENE_OBJECTS), replace=False)]
    others = [name for name in distractors if name not in own]
    count = NUM_SCENE_OBJECTS - len(mine)
    if len(others) < count:
        raise SceneError(f"need {count} distractors, got {len(others)}")
    chosen = [others[i] for i in rng.choice(len(others), size=count, replace=False)] if count else []
    texture = textures[rng.integers(len(textures))]
    return SceneSpec(tuple(mine + chosen), texture, held, int(rng.integers(2**31 - 1)))


def _tilted_yaw_quaternion(rng: np.random.Generator, max_tilt: float) -> np.ndarray:
    """A random yaw, then a tilt of at most `max_tilt` radians about a random horizontal axis."""
    yaw = rng.uniform(-np.pi, np.pi)
    tilt = rng.uniform(0.0, max_tilt)
    axis_angle = rng.uniform(-np.pi, np.pi)
    q_yaw = np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)])
    half = tilt / 2
    q_tilt = np.array([np.cos(half), np.sin(half) * np.cos(axis_angle), np.sin(half) * np.sin(axis_angle), 0.0])
    return quaternion_multiply(q_tilt, q_yaw)


def quaternion_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of (w, x, y, z) quaternions."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return np.array(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ]
    )


def quaternion_to_matrix(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def sample_drop_poses(
    seed: int,
    extents: list[tuple[float, float, float]],
    drop_half_extents: tuple[float, float],
    max_tilt: float = 0.35,
    clearance: float = 0.005,
) -> tuple[np.ndarray, np.ndarray]:
    """Initial poses above the central area, `(N, 3)` positions and `(N, 4)` quaternions.

    Objects may overlap in x-y (so they can come to rest partly on each other and occlude each
    other) but never interpenetrate at the start: each object's bounding sphere is raised above
    every earlier sphere it overlaps horizontally.
    """
    rng = np.random.default_rng(seed)
    positions, quaternions = [], []
    spheres: list[tuple[np.ndarray, float, float]] = []  # (x-y centre, height, radius) of each object dropped
    for extent in extents:
        size = np.asarray(extent, dtype=np.float64)
        radius = 0.5 * float(np.linalg.norm(size))
        xy = rng.uniform(-np.asarray(drop_half_extents), np.asarray(drop_half_extents))
        quaternion = _tilted_yaw_quaternion(rng, max_tilt)
        centre_z = radius + clearance
        for other_xy, other_z, other_radius in spheres:
            if np.linalg.norm(xy - other_xy) < radius + other_radius:
                centre_z = max(centre_z, other_z + radius + other_radius + clearance)
        spheres.append((xy, centre_z, radius))
        centre_offset = quaternion_to_matrix(quaternion) @ np.array([0.0, 0.0, size[2] / 2])
        positions.append(np.array([xy[0], xy[1], centre_z]) - centre_offset)
        quaternions.append(quaternion)
    return np.array(positions), np.array(quaternions)


def split_pools(library, split: str) -> tuple[list[str], list[str]]:
    """Object names of an object pool (a library split, or the seen colour variants) and the table textures
    that go with them.

    Textures are only seen or unseen: the unseen_cat objects lie on the unseen textures, the seen colour
    variants on the seen ones.
    """
    if split not in OBJECT_POOLS and split not in {asset.split for asset in library.objects.values()}:
        raise SceneError(f"unknown split {split!r}; choose one of {OBJECT_POOLS} or a subset of a built catalogue")
    texture_split = "seen" if split in ("seen", COLOUR_VARIANTS) else "unseen"
    textures = sorted(name for name, texture in library.textures.items() if texture.split == texture_split)
    objects = colour_variants(library) if split == COLOUR_VARIANTS else library.names(split)
    return objects, textures


def render_sampled_scene(library, arena, seed: int, split: str) -> RenderedScene:
    """Samples a scene of `split` from `seed` and builds it in `arena` (a `MujocoScenes`)."""
    objects, textures = split_pools(library, split)
    return arena.build(sample_scene_spec(np.random.default_rng(seed), objects, textures))


def retry_seed(seed: int, attempt: int) -> int:
    """The drop seed of the `attempt`-th retry of a scene whose objects fell off the table."""
    return int(np.random.default_rng([seed, attempt]).integers(2**31 - 1))


def settle_until_still(step, poses, radii: np.ndarray, physics) -> int:
    """Steps a simulation until no object point moves faster than `physics.settle_speed`.

    `step(n)` advances n steps; `poses()` gives `(N, 3)` positions and `(N, 4)` (w, x, y, z)
    quaternions. Speeds are net motion over each check window (displacement plus rotation angle
    x bounding radius, divided by the window's duration): resting objects in soft contacts jitter
    in place with instantaneous speeds of a few mm/s but do not go anywhere. The scene is still
    after `physics.still_checks` consecutive windows below the speed. Returns the steps taken.
    """
    max_steps = int(physics.max_settle_time / physics.timestep)
    window = physics.check_every * physics.timestep
    steps = still = 0
    positions, quaternions = poses()
    while steps < max_steps and still < physics.still_checks:
        step(physics.check_every)
        steps += physics.check_every
        new_positions, new_quaternions = poses()
        cosine = np.clip(np.abs(np.sum(new_quaternions * quaternions, axis=1)), 0.0, 1.0)
        travel = np.linalg.norm(new_positions - positions, axis=1) + 2.0 * np.arccos(cosine) * radii
        positions, quaternions = new_positions, new_quaternions
        still = still + 1 if travel.max(initial=0.0) / window < physics.settle_speed else 0
    return steps
