"""MuJoCo physics and offscreen rendering of scenes.

Compiling a model and creating an OpenGL context cost far more than settling and rendering a
scene, so `MujocoScenes` compiles ONE model holding the table and every object of the library
and keeps ONE renderer. A scene activates its objects: the others are parked far away with
gravity compensation, no contacts and their geoms in a hidden group.
"""

from __future__ import annotations

import dataclasses
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from pathlib import Path

import mujoco
import numpy as np
import trimesh

from ocplace.errors import ObjectsFellOff, SceneError
from ocplace.sim.camera import DEFAULT_CAMERA, Camera
from ocplace.sim.library.types import CORPUS_SPLIT, ObjectAsset
from ocplace.sim.render import OffscreenCamera
from ocplace.sim.scene import RenderedScene, SceneObject, SceneSpec, retry_seed, sample_drop_poses, settle_until_still
from ocplace.sim.trimesh_io import read_trimesh
from ocplace.sim.workspace import DEFAULT_TABLE, Table

VISIBLE_GROUP = 1
COLLISION_GROUP = 3
HIDDEN_GROUP = 5


@dataclasses.dataclass(frozen=True)
class PhysicsConfig:
    timestep: float = 0.004
    # Settled: no point of any object moves faster than this (m/s), net over each check window
    # (see `settle_until_still`).
    settle_speed: float = 0.005
    max_settle_time: float = 3.0  # s of simulated time before giving up on settling
    check_every: int = 25  # steps per settle window (100 ms: longer than contact jitter periods)
    # Free-joint damping (N s/m and N m s/rad): negligible on falls, but it stops curved objects
    # (bowls, plates) rocking or spinning on their hulls for seconds.
    damping: float = 0.0005
    still_checks: int = 2  # consecutive still windows: a slowly tipping object is not settled
    max_tilt: float = 0.35  # rad, largest initial tilt of a dropped object
    # Sliding, torsional and rolling friction. Without rolling friction a ball or a can on its
    # side rolls until it leaves the table.
    friction: tuple[float, float, float] = (0.9, 0.005, 0.003)
    # Elliptic friction cones with a high impedance ratio stop resting objects creeping, so
    # scenes settle in fewer steps than with pyramidal cones.
    cone: str = "elliptic"
    impratio: float = 10.0


@dataclasses.dataclass(frozen=True)
class ArenaRenderConfig:
    # Shadows and reflections are off: on a CPU (llvmpipe) they triple the render time and the
    # benchmark's camera sees the scene from straight above, where they add little.
    shadows: bool = False
    reflections: bool = False
    table_texture_repeat: float = 2.0  # texture repeats per metre of table
    # Multisample anti-aliasing of the offscreen buffer: 4 samples cost more than the rest of
    # a render on llvmpipe and only soften object edges.
    multisamples: int = 0


@dataclasses.dataclass(frozen=True)
class ArenaConfig:
    physics: PhysicsConfig = PhysicsConfig()
    render: ArenaRenderConfig = ArenaRenderConfig()
    camera: Camera = DEFAULT_CAMERA
    table: Table = DEFAULT_TABLE


def default_config() -> ArenaConfig:
    return ArenaConfig()


def _hull_volume(path: Path) -> float:
    return float(read_trimesh(path).convex_hull.volume)


def arena_xml(objects: Sequence[ObjectAsset], textures: dict[str, Path], config: ArenaConfig) -> str:
    """The MJCF of the table, the camera and every object parked off to the side."""
    camera, table, physics = config.camera, config.table, config.physics
    root = ET.Element("mujoco", model="ocplace_arena")
    ET.SubElement(root, "compiler", angle="radian", autolimits="true")
    option = ET.SubElement(
        root,
        "option",
        timestep=str(physics.timestep),
        integrator="implicitfast",
        cone=physics.cone,
        impratio=str(physics.impratio),
    )
    # One contact point per convex pair lets flat objects rock and slide for seconds; several
    # contacts per pair make them rest at once. Sleeping lets parked objects cost nothing.
    ET.SubElement(option, "flag", multiccd="enable", sleep="enable")
    visual = ET.SubElement(root, "visual")
    ET.SubElement(visual, "global", offwidth=str(camera.width), offheight=str(camera.height))
    ET.SubElement(
        visual,
        "quality",
        shadowsize="0" if not config.render.shadows else "4096",
        offsamples=str(config.render.multisamples),
    )
    ET.SubElement(visual, "headlight", ambient="0.45 0.45 0.45", diffuse="0.45 0.45 0.45", specular="0 0 0")
    # Clipping planes scale with the model extent, which parked objects would inflate: pin it so
    # near = 0.015 m and far = 7.5 m whatever the library holds.
    ET.SubElement(root, "statistic", extent="1.5", center="0 0 0")
    ET.SubElement(visual, "map", znear="0.01", zfar="5")
    default = ET.SubElement(ET.SubElement(root, "default"), "geom", friction=" ".join(map(str, physics.friction)))
    default.set("condim", "6")
    asset = ET.SubElement(root, "asset")
    world = ET.SubElement(root, "worldbody")

    repeat = config.render.table_texture_repeat
    for index, (name, path) in enumerate(sorted(textures.items())):
        ET.SubElement(asset, "texture", name=f"table_tex_{index}", type="2d", file=str(path))
        ET.SubElement(
            asset,
            "material",
            name=f"table_{name}",
            texture=f"table_tex_{index}",
            texrepeat=f"{repeat} {repeat}",
            texuniform="true",
            specular="0.05",
            shininess="0.05",
        )
    hx, hy = table.half_extents
    first_material = f"table_{sorted(textures)[0]}" if textures else None
    table_geom = ET.SubElement(
        world,
        "geom",
        name="table",
        type="box",
        size=f"{hx} {hy} {table.thickness / 2}",
        pos=f"0 0 {-table.thickness / 2}",
        group=str(VISIBLE_GROUP),
    )
    if first_material:
        table_geom.set("material", first_material)
    ET.SubElement(
        world,
        "geom",
        name="floor",
        type="plane",
        size="3 3 0.1",
        pos="0 0 -0.75",
        rgba="0.25 0.25 0.27 1",
        group=str(VISIBLE_GROUP),
    )
    ET.SubElement(
        world,
        "light",
        name="top",
        directional="true",
        pos="0 0 2",
        dir="0.2 0.3 -1",
        diffuse="0.5 0.5 0.5",
        specular="0.05 0.05 0.05",
        castshadow=str(config.render.shadows).lower(),
    )
    ET.SubElement(
        world,
        "camera",
        name="top",
        pos=" ".join(map(str, camera.position)),
        xyaxes="1 0 0 0 1 0",
        fovy=f"{camera.fov_y_deg:.6f}",
    )

    for index, obj in enumerate(objects):
        _add_object(asset, world, index, obj, physics.damping)
    ET.indent(root)
    return ET.tostring(root, encoding="unicode")


def _parking_position(index: int) -> tuple[float, float, float]:
    return (20.0 + (index % 10), 20.0 + (index // 10), 1.0)


def visual_geom_name(obj_name: str, part: int) -> str:
    """The visual geom of part `part` of an object (part 0 keeps the name single-part objects always had)."""
    return f"{obj_name}_visual" if part == 0 else f"{obj_name}_visual{part}"


def _add_object(asset: ET.Element, world: ET.Element, index: int, obj: ObjectAsset, damping: float) -> None:
    prefix = f"o{index}"
    volumes = [_hull_volume(path) for path in obj.hulls]
    density = obj.mass / max(sum(volumes), 1e-9)
    x, y, z = _parking_position(index)
    body = ET.SubElement(world, "body", name=obj.name, pos=f"{x} {y} {z}", gravcomp="1")
    ET.SubElement(body, "joint", name=f"{obj.name}_joint", type="free", damping=str(damping))
    # A visual mesh carries no mass; "shell" lets MuJoCo accept open ones (a corpus model's label or
    # screen is a single sheet, of zero volume). Library objects keep the default their datasets were
    # rendered with: it places the mesh frame differently, which changes the last bits of a render.
    open_mesh = {"inertia": "shell"} if obj.split == CORPUS_SPLIT else {}
    for part_index, part in enumerate(obj.visual_parts):
        part_prefix = prefix if part_index == 0 else f"{prefix}p{part_index}"
        material = f"{part_prefix}_mat"
        if part.texture is not None:
            ET.SubElement(asset, "texture", name=f"{part_prefix}_tex", type="2d", file=str(part.texture))
            ET.SubElement(
                asset,
                "material",
                name=material,
                texture=f"{part_prefix}_tex",
                rgba=" ".join(map(str, part.rgba)),
                specular="0.1",
                shininess="0.1",
            )
        else:
            ET.SubElement(asset, "material", name=material, rgba=" ".join(map(str, part.rgba)), specular="0.1")
        ET.SubElement(asset, "mesh", {"name": f"{part_prefix}_visual", "file": str(part.mesh), **open_mesh})
        ET.SubElement(
            body,
            "geom",
            name=visual_geom_name(obj.name, part_index),
            type="mesh",
            mesh=f"{part_prefix}_visual",
            material=material,
            contype="0",
            conaffinity="0",
            density="0",
            group=str(HIDDEN_GROUP),
        )
    for hull_index, path in enumerate(obj.hulls):
        mesh_name = f"{prefix}_hull{hull_index}"
        ET.SubElement(asset, "mesh", name=mesh_name, file=str(path))
        ET.SubElement(
            body,
            "geom",
            name=f"{obj.name}_hull{hull_index}",
            type="mesh",
            mesh=mesh_name,
            density=f"{density:.6f}",
            group=str(COLLISION_GROUP),
            rgba="0 0 0 0",
        )


class MujocoScenes:
    """Builds, settles and renders scenes; reuse one instance for many scenes, then `close()`."""

    @classmethod
    def from_library(
        cls, library, names: Sequence[str] | None = None, config: ArenaConfig | None = None
    ) -> MujocoScenes:
        """An arena of `names` (default: every object) and every table texture of `library`."""
        objects = [library.get(name) for name in (library.names() if names is None else names)]
        textures = {name: texture.path for name, texture in library.textures.items()}
        return cls(objects, textures, config)

    def __init__(self, objects: Sequence[ObjectAsset], textures: dict[str, Path], config: ArenaConfig | None = None):
        self.config = config or default_config()
        self.objects = {obj.name: obj for obj in objects}
        self._order = [obj.name for obj in objects]
        self._texture_names = sorted(textures)
        self.model = mujoco.MjModel.from_xml_string(arena_xml(objects, textures, self.config))
        self.data = mujoco.MjData(self.model)
        self._body = {name: self.model.body(name).id for name in self._order}
        self._tree = {name: self.model.body_treeid[body] for name, body in self._body.items()}
        self._hull_vertices: dict[str, np.ndarray] = {}  # made on first use: most scenes use few objects
        self._table_geom = self.model.geom("table").id
        self._visual_geoms = {
            obj.name: [self.model.geom(visual_geom_name(obj.name, k)).id for k in range(len(obj.visual_parts))]
            for obj in objects
        }
        self._collision_geoms = {
            obj.name: [self.model.geom(f"{obj.name}_hull{i}").id for i in range(len(obj.hulls))] for obj in objects
        }
        self._scene_option = mujoco.MjvOption()
        self._scene_option.geomgroup[:] = 0
        self._scene_option.geomgroup[VISIBLE_GROUP] = 1
        self._camera: OffscreenCamera | None = None
        self._active: tuple[str, ...] = ()
        # Hull geoms are compiled as colliding (MuJoCo prepares the convex-hull data that
        # multi-point contacts need only for those) and switched off here until a scene uses them.
        self.activate(())

    # Lifecycle -------------------------------------------------------------------------------
    def __enter__(self) -> MujocoScenes:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        if self._camera is not None:
            self._camera.close()
            self._camera = None

    @property
    def camera(self) -> OffscreenCamera:
        if self._camera is None:
            camera, render = self.config.camera, self.config.render
            self._camera = OffscreenCamera(
                self.model, "top", camera.width, camera.height, self._scene_option, render.shadows, render.reflections
            )
        return self._camera

    # Scene set-up ----------------------------------------------------------------------------
    def activate(self, names: Sequence[str], table_texture: str | None = None) -> None:
        """Resets the simulation with only `names` taking part in physics and rendering."""
        unknown = [name for name in names if name not in self.objects]
        if unknown:
            raise SceneError(f"objects {unknown} are not in this arena; rebuild it with them")
        for name in self._order:
            # Parked objects start every episode asleep; scene objects never sleep, so their
            # physics is what it would be without sleeping.
            self.model.tree_sleep_policy[self._tree[name]] = (
                mujoco.mjtSleepPolicy.mjSLEEP_NEVER if name in names else mujoco.mjtSleepPolicy.mjSLEEP_INIT
            )
        mujoco.mj_resetData(self.model, self.data)
        for name in self._order:
            active = name in names
            body = self._body[name]
            self.model.body_gravcomp[body] = 0.0 if active else 1.0
            # MuJoCo filters contacts per body before per geom, so both levels are switched.
            self.model.body_contype[body] = int(active)
            self.model.body_conaffinity[body] = int(active)
            self.model.geom_group[self._visual_geoms[name]] = VISIBLE_GROUP if active else HIDDEN_GROUP
            for geom in self._collision_geoms[name]:
                self.model.geom_contype[geom] = int(active)
                self.model.geom_conaffinity[geom] = int(active)
        if table_texture is not None:
            if table_texture not in self._texture_names:
                raise SceneError(f"unknown table texture {table_texture!r}; known: {self._texture_names}")
            self.model.geom_matid[self._table_geom] = self.model.material(f"table_{table_texture}").id
        self._active = tuple(names)
        mujoco.mj_forward(self.model, self.data)

    def set_poses(self, names: Sequence[str], positions: np.ndarray, quaternions: np.ndarray) -> None:
        for name, position, quaternion in zip(names, positions, quaternions, strict=True):
            address = self.model.jnt_qposadr[self.model.body_jntadr[self._body[name]]]
            self.data.qpos[address : address + 3] = position
            self.data.qpos[address + 3 : address + 7] = quaternion
        mujoco.mj_forward(self.model, self.data)

    def poses(self, names: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
        """`(N, 3)` positions and `(N, 4)` quaternions of the named objects."""
        positions = np.array([self.data.xpos[self._body[name]] for name in names])
        quaternions = np.array([self.data.xquat[self._body[name]] for name in names])
        return positions, quaternions

    def settle(self, names: Sequence[str] | None = None) -> int:
        """Steps until every named object is still; returns the number of steps taken."""
        physics = self.config.physics
        names = self._active if names is None else names
        radii = np.array([0.5 * np.linalg.norm(self.objects[n].extents) for n in names])
        return settle_until_still(
            lambda n: mujoco.mj_step(self.model, self.data, nstep=n), lambda: self.poses(names), radii, physics
        )

    # Outputs ---------------------------------------------------------------------------------
    def aabbs(self, names: Sequence[str]) -> np.ndarray:
        """`(N, 2, 3)` world-frame AABBs of the named objects in their current poses."""
        boxes = []
        for name in names:
            body = self._body[name]
            rotation = self.data.xmat[body].reshape(3, 3)
            if name not in self._hull_vertices:
                self._hull_vertices[name] = object_hull_points(self.objects[name])
            points = self._hull_vertices[name] @ rotation.T + self.data.xpos[body]
            boxes.append(np.stack([points.min(axis=0), points.max(axis=0)]))
        return np.array(boxes)

    def render(self, names: Sequence[str] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """RGB `(H, W, 3)` uint8, planar depth `(H, W)` float32 metres, object ids `(H, W)` int32.

        Object ids follow the order of `names` (default: the active objects), starting at 1.
        """
        names = self._active if names is None else names
        rgb, depth, geom_ids = self.camera.render(self.data)
        lookup = np.zeros(self.model.ngeom + 1, dtype=np.int32)  # last entry catches background -1
        for object_id, name in enumerate(names, start=1):
            lookup[self._visual_geoms[name]] = object_id
        segmentation = lookup[geom_ids]
        return rgb, depth, segmentation

    def scene_objects(self, names: Sequence[str]) -> tuple[SceneObject, ...]:
        positions, quaternions = self.poses(names)
        aabbs = self.aabbs(names)
        return tuple(
            SceneObject(i + 1, name, positions[i].copy(), quaternions[i].copy(), aabbs[i])
            for i, name in enumerate(names)
        )

    def build(self, spec: SceneSpec, max_attempts: int = 5) -> RenderedScene:
        """Drops the spec's objects over the table, settles them and renders the camera view.

        When an object falls off the table the drop is repeated with a seed derived from the
        spec's (`retry_seed`); the returned scene's spec holds the seed that was used.
        """
        for attempt in range(max_attempts):
            try:
                return self._build_once(spec)
            except ObjectsFellOff:
                spec = dataclasses.replace(spec, seed=retry_seed(spec.seed, attempt))
        raise SceneError(f"objects of scene {spec} fell off the table {max_attempts} times in a row")

    def _build_once(self, spec: SceneSpec) -> RenderedScene:
        names = spec.objects
        self.activate(names, spec.table_texture)
        extents = [self.objects[name].extents for name in names]
        positions, quaternions = sample_drop_poses(
            spec.seed, extents, self.config.table.drop_half_extents, self.config.physics.max_tilt
        )
        self.set_poses(names, positions, quaternions)
        steps = self.settle(names)
        objects = self.scene_objects(names)
        fallen = [obj.name for obj in objects if obj.aabb[0, 2] < -0.01 or not self._on_table(obj)]
        if fallen:
            raise ObjectsFellOff(f"scene seed {spec.seed}: {fallen} fell off the table")
        rgb, depth, segmentation = self.render(names)
        return RenderedScene(spec, objects, rgb, depth, segmentation, steps)

    def _on_table(self, obj: SceneObject) -> bool:
        centre = obj.aabb[:, :2].mean(axis=0)
        return bool(np.all(np.abs(centre) <= np.asarray(self.config.table.half_extents)))


def object_hull_points(obj: ObjectAsset) -> np.ndarray:
    """`(P, 3)` vertices of the convex hull of the visual meshes, in the object frame."""
    points = [read_trimesh(part.mesh, skip_materials=True).vertices for part in obj.visual_parts]
    return np.asarray(trimesh.convex.convex_hull(np.concatenate(points)).vertices)
