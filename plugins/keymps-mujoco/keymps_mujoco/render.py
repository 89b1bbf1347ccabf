"""Offscreen rendering of a SimScene's cameras (MUJOCO_GL: egl by default, osmesa as fallback).

One OpenGL context and one MuJoCo render context serve every camera; each camera renders into
its own viewport of the offscreen buffer. The top-down camera can hide the arm (the outcome
image shows what the tool did, not the arm), and the painted texture on the tops is uploaded
again whenever it changes.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from keymps.plugin import KeympsError
from keymps_mujoco.model import ARM_GROUP, SimScene


def ensure_gl_backend() -> str:
    """MUJOCO_GL as set, else egl (headless, Mesa's software renderer where there is no GPU)."""
    return os.environ.setdefault("MUJOCO_GL", "egl")


class Renderer:
    """Renders the scene's named cameras to BGR images (OpenCV's channel order)."""

    def __init__(self, scene: SimScene, max_geom: int = 4000):
        backend = ensure_gl_backend()
        import mujoco

        self.scene = scene
        model = scene.model
        self.width = int(model.vis.global_.offwidth)
        self.height = int(model.vis.global_.offheight)
        try:
            self.gl = mujoco.GLContext(self.width, self.height)
            self.gl.make_current()
        except Exception as error:  # no EGL/OSMesa library, no display ...
            raise KeympsError(
                f"mujoco: cannot create an offscreen OpenGL context with MUJOCO_GL={backend} "
                f"({error}); install Mesa's EGL (libegl1) or set MUJOCO_GL=osmesa"
            ) from None
        self.context = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_100)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self.context)
        self.mjv_scene = mujoco.MjvScene(model, maxgeom=max_geom)
        self.option = mujoco.MjvOption()
        self.camera = mujoco.MjvCamera()
        self.camera.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self.perturb = mujoco.MjvPerturb()

    def upload_texture(self, rgb: np.ndarray) -> None:
        """Replace the tops' texture (an RGB image spanning the workspace, row 0 at the top)."""
        import mujoco

        scene = self.scene
        if scene.texture_id < 0:
            return
        model = scene.model
        start = int(model.tex_adr[scene.texture_id])
        flipped = np.ascontiguousarray(rgb[::-1], dtype=np.uint8).ravel()
        model.tex_data[start : start + flipped.size] = flipped
        self.gl.make_current()
        mujoco.mjr_uploadTexture(model, self.context, scene.texture_id)

    def render(
        self,
        camera: str,
        size_px: tuple[int, int],
        show_arm: bool = True,
        extra: Any = None,
        shadows: bool = False,
    ) -> np.ndarray:
        """The camera's image (BGR uint8, size_px = (width, height)); `extra(scene)` may add
        decoration geoms (icing deposits) after the scene is updated. Shadows triple the cost
        of a frame with Mesa's software renderer."""
        import mujoco

        model, data = self.scene.model, self.scene.data
        width, height = size_px
        if width > self.width or height > self.height:
            raise KeympsError(f"mujoco: {width}x{height} exceeds the offscreen buffer")
        self.camera.fixedcamid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, camera)
        self.option.geomgroup[ARM_GROUP] = 1 if show_arm else 0
        self.option.sitegroup[:] = 0
        mujoco.mjv_updateScene(
            model,
            data,
            self.option,
            self.perturb,
            self.camera,
            mujoco.mjtCatBit.mjCAT_ALL,
            self.mjv_scene,
        )
        self.mjv_scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = int(shadows)
        if extra is not None:
            extra(self.mjv_scene)
        self.gl.make_current()
        viewport = mujoco.MjrRect(0, 0, width, height)
        mujoco.mjr_render(viewport, self.mjv_scene, self.context)
        rgb = np.empty((height, width, 3), np.uint8)
        mujoco.mjr_readPixels(rgb, None, viewport, self.context)
        return np.ascontiguousarray(rgb[::-1, :, ::-1])

    def close(self) -> None:
        context, self.context = self.context, None
        if context is not None:
            context.free()
        gl, self.gl = getattr(self, "gl", None), None
        if gl is not None:
            gl.free()

    def __enter__(self) -> Renderer:
        return self

    def __exit__(self, *_: object) -> None:
        self.close()
