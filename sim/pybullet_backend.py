"""The same scenes in PyBullet, for parity checks against MuJoCo.

Objects come from the same processed meshes (the library's URDFs); the camera has the same
intrinsics and pose, expressed as OpenGL view and projection matrices. Like the MuJoCo arena,
objects are loaded once and parked (static, far away) while a scene does not use them.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pybullet
from pybullet_utils import bullet_client

from ocplace.errors import SceneError
from ocplace.sim.library.types import ObjectAsset
from ocplace.sim.mujoco_backend import ArenaConfig, default_config
from ocplace.sim.scene import SceneObject, SceneSpec, quaternion_to_matrix, sample_drop_poses, settle_until_still

RENDERERS = ("tiny", "egl")
# PyBullet's contacts need smaller steps than MuJoCo's implicit integrator: at 4 ms, balls and
# cans dropped on a pile sometimes bounce off the table; at 2 ms they settle like in MuJoCo.
TIMESTEP = 0.002
# With the same rolling-friction coefficient as MuJoCo's, a PyBullet ball still rolls off the
# table; this value stops it within the settle time like MuJoCo's 0.003 does.
ROLLING_FRICTION = 0.03


def _xyzw(quaternion_wxyz: np.ndarray) -> list[float]:
    w, x, y, z = quaternion_wxyz
    return [x, y, z, w]


def _wxyz(quaternion_xyzw: Sequence[float]) -> np.ndarray:
    x, y, z, w = quaternion_xyzw
    return np.array([w, x, y, z])


class PybulletScenes:
    """PyBullet twin of `MujocoScenes`: same objects, table, camera and drop poses."""

    near, far = 0.015, 7.5  # clipping planes, metres: the same as the MuJoCo arena's

    def __init__(
        self,
        objects: Sequence[ObjectAsset],
        textures: dict[str, Path],
        config: ArenaConfig | None = None,
        renderer: str = "tiny",
    ):
        if renderer not in RENDERERS:
            raise SceneError(f"unknown PyBullet renderer {renderer!r}; choose one of {RENDERERS}")
        config = config or default_config()
        window_steps = round(config.physics.check_every * config.physics.timestep / TIMESTEP)
        physics = dataclasses.replace(config.physics, timestep=TIMESTEP, check_every=window_steps)
        self.config = dataclasses.replace(config, physics=physics)
        self.objects = {obj.name: obj for obj in objects}
        self.client = bullet_client.BulletClient(connection_mode=pybullet.DIRECT)
        self.client.setGravity(0, 0, -9.81)
        self.client.setTimeStep(self.config.physics.timestep)
        self._renderer_flag = pybullet.ER_TINY_RENDERER
        if renderer == "egl":
            self._load_egl()
        self._textures = {name: self.client.loadTexture(str(path)) for name, path in textures.items()}
        self._table = self._add_table()
        self._bodies: dict[str, int] = {}
        self._active: tuple[str, ...] = ()
        self._view, self._projection = self._camera_matrices()
        self._render_projection = self._pixel_centred(self._projection) if renderer == "tiny" else self._projection

    def close(self) -> None:
        if self.client is not None:
            self.client.disconnect()
            self.client = None

    def __enter__(self) -> PybulletScenes:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _load_egl(self) -> None:
        import importlib.util

        egl = importlib.util.find_spec("eglRenderer")
        if egl is None or egl.origin is None or self.client.loadPlugin(egl.origin, "_eglRendererPlugin") < 0:
            raise SceneError("PyBullet's EGL renderer plugin could not be loaded; use renderer='tiny'")
        self._renderer_flag = pybullet.ER_BULLET_HARDWARE_OPENGL

    def _add_table(self) -> int:
        table = self.config.table
        half = [*table.half_extents, table.thickness / 2]
        shape = self.client.createCollisionShape(pybullet.GEOM_BOX, halfExtents=half)
        visual = self.client.createVisualShape(pybullet.GEOM_BOX, halfExtents=half)
        body = self.client.createMultiBody(0, shape, visual, basePosition=[0, 0, -table.thickness / 2])
        floor = self.client.createCollisionShape(pybullet.GEOM_PLANE)
        floor_visual = self.client.createVisualShape(
            pybullet.GEOM_BOX, halfExtents=[3, 3, 0.001], rgbaColor=[0.25, 0.25, 0.27, 1]
        )
        self.client.createMultiBody(0, floor, floor_visual, basePosition=[0, 0, -0.75])
        sliding, spinning, _ = self.config.physics.friction
        self.client.changeDynamics(
            body, -1, lateralFriction=sliding, spinningFriction=spinning, rollingFriction=ROLLING_FRICTION
        )
        return body

    def _camera_matrices(self) -> tuple[list[float], list[float]]:
        camera = self.config.camera
        view = self.client.computeViewMatrix(
            cameraEyePosition=list(camera.position),
            cameraTargetPosition=[camera.position[0], camera.position[1], 0.0],
            cameraUpVector=[0, 1, 0],
        )
        projection = self.client.computeProjectionMatrixFOV(
            fov=camera.fov_y_deg, aspect=camera.width / camera.height, nearVal=self.near, farVal=self.far
        )
        return view, projection

    def _pixel_centred(self, projection: list[float]) -> list[float]:
        """Shifts the image by half a pixel left and down.

        TinyRenderer samples each pixel at its corner, not its centre: measured on our scenes, its
        masks sit (-0.5, +0.5) px (rows, columns) off MuJoCo's. The shift makes both engines
        sample pixel centres, as the camera model assumes.
        """
        camera = self.config.camera
        matrix = np.asarray(projection).reshape(4, 4, order="F").copy()
        matrix[0] -= matrix[3] / camera.width
        matrix[1] -= matrix[3] / camera.height
        return matrix.reshape(-1, order="F").tolist()

    def _body(self, name: str) -> int:
        if name not in self._bodies:
            asset = self.objects.get(name)
            if asset is None:
                raise SceneError(f"object {name!r} is not in this PyBullet arena")
            body = self.client.loadURDF(
                str(asset.urdf),
                basePosition=self._parking(len(self._bodies)),
                flags=pybullet.URDF_USE_INERTIA_FROM_FILE,
            )
            if asset.texture is not None:
                texture = self.client.loadTexture(str(asset.texture))
                self.client.changeVisualShape(body, -1, textureUniqueId=texture, rgbaColor=[1, 1, 1, 1])
            sliding, spinning, _ = self.config.physics.friction
            self.client.changeDynamics(
                body, -1, lateralFriction=sliding, spinningFriction=spinning, rollingFriction=ROLLING_FRICTION, mass=0.0
            )
            self._bodies[name] = body
        return self._bodies[name]

    @staticmethod
    def _parking(index: int) -> list[float]:
        return [20.0 + index, 20.0, 1.0]

    def activate(self, names: Sequence[str], table_texture: str | None = None) -> None:
        """Parks every object not in `names` as a static body far away; `names` become dynamic."""
        for index, name in enumerate(self._bodies):
            if name not in names:
                self.client.changeDynamics(self._bodies[name], -1, mass=0.0)
                self.client.resetBasePositionAndOrientation(self._bodies[name], self._parking(index), [0, 0, 0, 1])
        for name in names:
            self.client.changeDynamics(self._body(name), -1, mass=self.objects[name].mass)
        if table_texture is not None:
            if table_texture not in self._textures:
                raise SceneError(f"unknown table texture {table_texture!r}; known: {sorted(self._textures)}")
            self.client.changeVisualShape(self._table, -1, textureUniqueId=self._textures[table_texture])
        self._active = tuple(names)

    def set_poses(self, names: Sequence[str], positions: np.ndarray, quaternions: np.ndarray) -> None:
        """Object-frame poses, (w, x, y, z) quaternions as in MuJoCo."""
        for name, position, quaternion in zip(names, positions, quaternions, strict=True):
            body = self._body(name)
            # PyBullet poses a URDF base by its inertial frame (centre of mass and principal axes).
            com, orientation = self.client.multiplyTransforms(
                list(position), _xyzw(quaternion), *self._inertial_frame(body)
            )
            self.client.resetBasePositionAndOrientation(body, com, orientation)
            self.client.resetBaseVelocity(body, [0, 0, 0], [0, 0, 0])

    def _inertial_frame(self, body: int) -> tuple[list[float], list[float]]:
        info = self.client.getDynamicsInfo(body, -1)
        return list(info[3]), list(info[4])

    def poses(self, names: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
        """`(N, 3)` object-frame positions and `(N, 4)` (w, x, y, z) quaternions."""
        positions, quaternions = [], []
        for name in names:
            body = self._body(name)
            com, orientation = self.client.getBasePositionAndOrientation(body)
            local_position, local_orientation = self.client.invertTransform(*self._inertial_frame(body))
            position, orientation = self.client.multiplyTransforms(com, orientation, local_position, local_orientation)
            positions.append(np.asarray(position))
            quaternions.append(_wxyz(orientation))
        return np.array(positions), np.array(quaternions)

    def settle(self, names: Sequence[str] | None = None) -> int:
        physics = self.config.physics
        names = self._active if names is None else names
        for name in names:
            self._body(name)  # loads bodies not yet in the world
        radii = np.array([0.5 * np.linalg.norm(self.objects[name].extents) for name in names])

        def step(count: int) -> None:
            for _ in range(count):
                self.client.stepSimulation()

        return settle_until_still(step, lambda: self.poses(names), radii, physics)

    def aabbs(self, names: Sequence[str], hull_points: dict[str, np.ndarray]) -> np.ndarray:
        """`(N, 2, 3)` world AABBs from each object's hull points (object frame)."""
        positions, quaternions = self.poses(names)
        boxes = []
        for name, position, quaternion in zip(names, positions, quaternions, strict=True):
            points = hull_points[name] @ quaternion_to_matrix(quaternion).T + position
            boxes.append(np.stack([points.min(axis=0), points.max(axis=0)]))
        return np.array(boxes)

    def render(self, names: Sequence[str] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """RGB `(H, W, 3)` uint8, planar depth `(H, W)` float32 metres, object ids `(H, W)` int32."""
        names = self._active if names is None else names
        camera = self.config.camera
        _, _, rgba, zbuffer, body_ids = self.client.getCameraImage(
            camera.width,
            camera.height,
            viewMatrix=self._view,
            projectionMatrix=self._render_projection,
            renderer=self._renderer_flag,
            shadow=0,
        )
        rgb = np.asarray(rgba, dtype=np.uint8).reshape(camera.height, camera.width, 4)[..., :3].copy()
        zbuffer = np.asarray(zbuffer, dtype=np.float64).reshape(camera.height, camera.width)
        depth = (self.far * self.near / (self.far - (self.far - self.near) * zbuffer)).astype(np.float32)
        body_ids = np.asarray(body_ids, dtype=np.int64).reshape(camera.height, camera.width)
        lookup = {self._body(name): object_id for object_id, name in enumerate(names, start=1)}
        segmentation = np.zeros(body_ids.shape, dtype=np.int32)
        for body, object_id in lookup.items():
            segmentation[body_ids == body] = object_id
        return rgb, depth, segmentation

    def drop(self, spec: SceneSpec, hull_points: dict[str, np.ndarray]) -> tuple[SceneObject, ...]:
        """Drops the spec's objects from the same initial poses as MuJoCo and settles them."""
        names = spec.objects
        self.activate(names, spec.table_texture)
        extents = [self.objects[name].extents for name in names]
        positions, quaternions = sample_drop_poses(
            spec.seed, extents, self.config.table.drop_half_extents, self.config.physics.max_tilt
        )
        self.set_poses(names, positions, quaternions)
        self.settle(names)
        positions, quaternions = self.poses(names)
        aabbs = self.aabbs(names, hull_points)
        return tuple(SceneObject(i + 1, name, positions[i], quaternions[i], aabbs[i]) for i, name in enumerate(names))
