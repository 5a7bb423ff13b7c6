"""Offscreen OpenGL rendering of a MuJoCo camera (EGL or OSMesa), used by :mod:`pal.sim.camera`.

Backend choice does not depend on ``MUJOCO_GL`` having been set before ``import mujoco``:
the GL context is created here directly from ``mujoco.egl`` or ``mujoco.osmesa`` (or
``mujoco.glfw`` when asked for explicitly). The order tried is ``MUJOCO_GL`` (if it names
one of these) and then EGL, then OSMesa. One caveat remains: PyOpenGL binds its platform
(``PYOPENGL_PLATFORM``) when it is first imported in the process, so once one platform has
been loaded the others fail; a failed backend is remembered and not tried again.

Findings with mujoco 4.0.0 on Linux: ``MUJOCO_GL=osmesa`` without libOSMesa makes
``import mujoco`` itself fail (PyOpenGL raises AttributeError, which mujoco does not
catch), so it cannot be handled here; leave ``MUJOCO_GL`` unset or set it to ``egl``.
``mujoco.glfw`` without a display returns a context without a window, on which
``MjrContext`` would crash the process; GLFW is therefore only tried when ``DISPLAY`` or
``WAYLAND_DISPLAY`` is set.
"""

from __future__ import annotations

import importlib
import logging
import os
import sys
from typing import Any

import mujoco
import numpy as np

__all__ = ["GL_BACKENDS", "GLRenderer", "RenderBackendError", "gl_backend_order"]

logger = logging.getLogger(__name__)

#: GL backends this module can open.
GL_BACKENDS = ("egl", "osmesa", "glfw")

_DISABLED = ("disable", "disabled", "off", "false", "0")
_FAILED: dict[str, str] = {}


class RenderBackendError(RuntimeError):
    """No OpenGL context could be created with the requested backend(s)."""


def gl_backend_order(backend: str = "auto") -> list[str]:
    """Backends to try, in order, for ``backend`` ("auto", "gl" or one of :data:`GL_BACKENDS`).

    ``MUJOCO_GL=disable`` (or off/false/0) means no GL for "auto" and "gl": an empty list.
    """
    if backend in GL_BACKENDS:
        return [backend]
    env = os.environ.get("MUJOCO_GL", "").strip().lower()
    if env in _DISABLED:
        return []
    order = [env] if env in GL_BACKENDS else []
    return order + [b for b in ("egl", "osmesa") if b not in order]


def _open_context(backend: str, width: int, height: int) -> Any:
    if backend in _FAILED:
        raise RenderBackendError(f"{backend}: {_FAILED[backend]} (failed earlier in this process)")
    if (
        backend == "glfw"
        and sys.platform.startswith("linux")
        and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    ):
        # mujoco.glfw then "succeeds" with no window, and MjrContext would crash the process.
        raise RenderBackendError("glfw: no DISPLAY or WAYLAND_DISPLAY; GLFW needs a display server")
    try:
        module = importlib.import_module(f"mujoco.{backend}")
        ctx = module.GLContext(width, height)
        if hasattr(ctx, "_context") and not ctx._context:
            raise RuntimeError("the context was not created")
        ctx.make_current()
    except Exception as err:  # any failure of a third-party GL stack means "backend unavailable"
        _FAILED[backend] = f"{type(err).__name__}: {err}"
        logger.info("GL backend %s unavailable: %s", backend, _FAILED[backend])
        raise RenderBackendError(f"{backend}: {_FAILED[backend]}") from err
    return ctx


def open_context(backends: list[str], width: int, height: int) -> tuple[Any, str]:
    """Create and make current the first GL context that works.

    Returns:
        ``(context, backend_name)``.

    Raises:
        RenderBackendError: none of ``backends`` works; the message lists each failure.
    """
    if not backends:
        raise RenderBackendError(
            f"no OpenGL backend available: GL is disabled (MUJOCO_GL={os.environ.get('MUJOCO_GL')!r})"
        )
    errors = []
    for backend in backends:
        try:
            return _open_context(backend, width, height), backend
        except RenderBackendError as err:
            errors.append(str(err))
    raise RenderBackendError("no OpenGL backend available: " + "; ".join(errors))


class GLRenderer:
    """Rasterises one fixed camera: RGB, metric depth and geom segmentation.

    Args:
        model: the compiled model.
        cam_id: camera id.
        width, height: image size in pixels (at most the model's offscreen buffer,
            ``<visual><global offwidth offheight/>``).
        backends: GL backends to try, in order.
    """

    def __init__(
        self, model: mujoco.MjModel, cam_id: int, width: int, height: int, backends: list[str]
    ) -> None:
        self._ctx = None
        self._mjr = None
        buf_w, buf_h = int(model.vis.global_.offwidth), int(model.vis.global_.offheight)
        if width > buf_w or height > buf_h:
            raise ValueError(
                f"image size {width}x{height} exceeds the model's offscreen buffer {buf_w}x{buf_h}; "
                f'add <visual><global offwidth="{width}" offheight="{height}"/></visual> to the MJCF'
            )
        self.model, self.width, self.height = model, width, height
        self._ctx, self.backend = open_context(backends, width, height)
        self._mjr = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_150.value)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN.value, self._mjr)
        self._mjr.readDepthMap = mujoco.mjtDepthMap.mjDEPTH_ZEROFAR
        self._scene = mujoco.MjvScene(model, maxgeom=10000)
        self._option = mujoco.MjvOption()
        self._option.sitegroup[:] = 0  # sites are markers, not surfaces
        self._camera = mujoco.MjvCamera()
        self._camera.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self._camera.fixedcamid = cam_id
        self._rect = mujoco.MjrRect(0, 0, width, height)
        self._rgb = np.empty((height, width, 3), np.uint8)
        self._raw = np.empty((height, width), np.float32)
        self._seg = np.empty((height, width, 3), np.uint8)

    def render(self, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Render the current ``data`` (kinematics must be up to date).

        Returns:
            ``rgb`` (H, W, 3) uint8; ``depth`` (H, W) float32 in metres along the optical
            axis, 0 where nothing was hit; ``geom_ids`` (H, W) int32, -1 for background and
            for non-geom objects.
        """
        if self._mjr is None:
            raise RuntimeError("render called after close()")
        m = self.model
        self._ctx.make_current()
        mujoco.mjv_updateScene(
            m, data, self._option, None, self._camera, mujoco.mjtCatBit.mjCAT_ALL.value, self._scene
        )
        mujoco.mjr_render(self._rect, self._scene, self._mjr)
        mujoco.mjr_readPixels(self._rgb, None, self._rect, self._mjr)
        # Depth is read in the segmentation pass, so that depth and ids come from the same
        # samples: the shaded pass is multisampled and disagrees with them at silhouettes.
        flags = self._scene.flags.copy()
        try:
            self._scene.flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = True
            self._scene.flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = True
            mujoco.mjr_render(self._rect, self._scene, self._mjr)
            mujoco.mjr_readPixels(self._seg, self._raw, self._rect, self._mjr)
        finally:
            np.copyto(self._scene.flags, flags)
        # GL rows run bottom-up.
        rgb = np.flipud(self._rgb).copy()
        raw = np.flipud(self._raw).astype(np.float64)
        seg = np.flipud(self._seg).astype(np.int64)
        segid = seg[..., 0] + seg[..., 1] * 256 + seg[..., 2] * 65536  # 0 = nothing drawn
        ngeom = self._scene.ngeom
        lut = np.full(ngeom + 1, -1, np.int32)
        for i in range(ngeom):
            g = self._scene.geoms[i]
            if g.segid >= 0 and g.objtype == mujoco.mjtObj.mjOBJ_GEOM:
                lut[g.segid + 1] = g.objid
        geom_ids = lut[np.clip(segid, 0, ngeom)]
        # Reversed-Z depth buffer (mjDEPTH_ZEROFAR): raw 1 at the near plane, 0 at the far
        # plane; metric depth d = f n / (n + raw (f - n)).
        near = float(m.vis.map.znear * m.stat.extent)
        far = float(m.vis.map.zfar * m.stat.extent)
        depth = far * near / (near + raw * (far - near))
        depth[(segid == 0) | (raw <= 0)] = 0.0
        return rgb, depth.astype(np.float32), geom_ids

    def close(self) -> None:
        """Free the GL resources (idempotent).

        The MjrContext is freed with its own GL context current (and the previously current
        one restored): freed under another context, its framebuffer and texture ids would
        delete that context's objects and corrupt another camera's images.
        """
        ctx, mjr = self._ctx, self._mjr
        self._ctx = self._mjr = None
        if mjr is not None and ctx is not None:
            if hasattr(ctx, "as_current"):
                with ctx.as_current():
                    mjr.free()
            else:
                ctx.make_current()
                mjr.free()
        if ctx is not None:
            ctx.free()

    def __del__(self) -> None:
        self.close()
