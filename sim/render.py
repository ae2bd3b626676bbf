"""Offscreen RGB, depth and segmentation from one MuJoCo camera in two render passes.

`mujoco.Renderer` renders once per image kind. Depth and segmentation both come out of the flat
"segment" pass, so reading them from the same pass saves a third of the render time on a CPU.
"""

from __future__ import annotations

import mujoco
import numpy as np
from mujoco import gl_context


class OffscreenCamera:
    """Renders one named camera of `model`; call `close()` (or use `with`) to free the context."""

    def __init__(
        self,
        model: mujoco.MjModel,
        camera: str,
        width: int,
        height: int,
        option: mujoco.MjvOption,
        shadows: bool = False,
        reflections: bool = False,
    ):
        self._model = model
        self._option = option
        self._rect = mujoco.MjrRect(0, 0, width, height)
        self._camera = mujoco.MjvCamera()
        self._camera.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self._camera.fixedcamid = model.camera(camera).id
        self._scene = mujoco.MjvScene(model, maxgeom=max(1000, 2 * model.ngeom))
        self._scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = shadows
        self._scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = reflections
        self._scene.flags[mujoco.mjtRndFlag.mjRND_SKYBOX] = False
        self._gl = gl_context.GLContext(width, height)
        self._gl.make_current()
        self._context = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_100)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._context)
        self._context.readDepthMap = mujoco.mjtDepthMap.mjDEPTH_ZEROFAR
        self._rgb = np.empty((height, width, 3), dtype=np.uint8)
        self._ids = np.empty((height, width, 3), dtype=np.uint8)
        self._depth = np.empty((height, width), dtype=np.float32)

    def __enter__(self) -> OffscreenCamera:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        if self._gl is not None:
            self._gl.make_current()
            self._context.free()
            self._gl.free()
            self._gl = None

    def render(self, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """RGB `(H, W, 3)` uint8, planar depth `(H, W)` float32 metres, geom ids `(H, W)` int32.

        Geom id -1 marks pixels that show no geom.
        """
        if self._gl is None:
            raise RuntimeError("render called after close")
        self._gl.make_current()
        mujoco.mjv_updateScene(
            self._model, data, self._option, None, self._camera, mujoco.mjtCatBit.mjCAT_ALL, self._scene
        )
        mujoco.mjr_render(self._rect, self._scene, self._context)
        mujoco.mjr_readPixels(self._rgb, None, self._rect, self._context)
        rgb = np.flipud(self._rgb).copy()

        flags = self._scene.flags
        flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = True
        flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = True
        try:
            mujoco.mjr_render(self._rect, self._scene, self._context)
            mujoco.mjr_readPixels(self._ids, self._depth, self._rect, self._context)
        finally:
            flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = False
            flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = False
        depth = self._metric_depth(np.flipud(self._depth))
        return rgb, depth, self._geom_ids(np.flipud(self._ids))

    def _metric_depth(self, zbuffer: np.ndarray) -> np.ndarray:
        """Reversed-Z buffer values -> planar depth in metres (perspective camera)."""
        extent = self._model.stat.extent
        near = np.float32(self._model.vis.map.znear * extent)
        far = np.float32(self._model.vis.map.zfar * extent)
        c = -(far + near) / (far - near)
        d = -(np.float32(2) * far * near) / (far - near)
        c, d = np.float32(-0.5) * c - np.float32(0.5), np.float32(-0.5) * d
        return (d / (zbuffer.astype(np.float64) + c)).astype(np.float32)

    def _geom_ids(self, colours: np.ndarray) -> np.ndarray:
        """Segment colours encode the scene geom index + 1; map them to model geom ids."""
        segment = (
            colours[..., 0].astype(np.int32)
            | (colours[..., 1].astype(np.int32) << 8)
            | (colours[..., 2].astype(np.int32) << 16)
        )
        lookup = np.full(self._scene.ngeom + 2, -1, dtype=np.int32)
        for geom in self._scene.geoms[: self._scene.ngeom]:
            if geom.segid >= 0 and geom.objtype == mujoco.mjtObj.mjOBJ_GEOM:
                lookup[geom.segid + 1] = geom.objid
        return lookup[np.minimum(segment, len(lookup) - 1)]
