"""RGB, metric depth and segmentation from a named MuJoCo camera, with its intrinsics K.

Backends (``Camera(..., backend=...)``):

- ``"auto"`` (default): OpenGL offscreen if a context can be created (``MUJOCO_GL`` if it
  names egl/osmesa/glfw, then EGL, then OSMesa; see :mod:`pal.sim.render_gl`), else the
  ray-cast camera, with a logged warning. ``MUJOCO_GL=disable`` selects the ray-cast camera.
- ``"gl"``: OpenGL only (EGL, then OSMesa); :class:`RenderBackendError` if none works.
- ``"egl"``, ``"osmesa"``, ``"glfw"``: that backend only.
- ``"raycast"``: ``mj_multiRay`` per pixel, no GL (flat per-geom colours).

``MUJOCO_GL`` need not be set before ``import mujoco``: contexts are opened directly from
``mujoco.egl``/``mujoco.osmesa``. On this project's CI machine EGL (Mesa llvmpipe) works.

Conventions: K follows OpenCV (pixel centres at integer coordinates, x right, y down), with
``fy = H / (2 tan(fovy / 2))``, ``fx = fy`` (square pixels) and the principal point at
the image centre ``((W - 1) / 2, (H - 1) / 2)``. Depth is the z distance along the
optical axis in metres (what an RGB-D sensor reports), 0 where no surface was hit.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import mujoco
import numpy as np

from pal.sim.render_gl import GL_BACKENDS, GLRenderer, RenderBackendError, gl_backend_order
from pal.sim.render_ray import RayRenderer

__all__ = ["BACKENDS", "Camera", "CameraFrame", "RenderBackendError", "intrinsics"]

logger = logging.getLogger(__name__)

#: Accepted values of ``Camera(backend=...)``.
BACKENDS = ("auto", "gl", *GL_BACKENDS, "raycast")

# MuJoCo camera frame (x right, y up, looking along -z) -> OpenCV (x right, y down, z forward).
_MJ_TO_CV = np.diag([1.0, -1.0, -1.0])


def intrinsics(fovy_deg: float, width: int, height: int) -> np.ndarray:
    """Pinhole intrinsics of a camera with vertical field of view ``fovy_deg``.

    Args:
        fovy_deg: vertical field of view, degrees, in (0, 180).
        width: image width W, pixels.
        height: image height H, pixels.

    Returns:
        K, (3, 3) float64: ``[[f, 0, (W-1)/2], [0, f, (H-1)/2], [0, 0, 1]]`` with
        ``f = H / (2 tan(fovy/2))`` pixels.
    """
    if not 0 < fovy_deg < 180:
        raise ValueError(f"fovy must be in (0, 180) degrees, got {fovy_deg}")
    if width < 1 or height < 1:
        raise ValueError(f"image size must be positive, got {width}x{height}")
    f = height / (2.0 * math.tan(math.radians(fovy_deg) / 2.0))
    return np.array([[f, 0.0, (width - 1) / 2.0], [0.0, f, (height - 1) / 2.0], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class CameraFrame:
    """One rendered view.

    Attributes:
        rgb: (H, W, 3) uint8.
        depth: (H, W) float32, metres along the optical axis; 0 = no surface.
        segmentation: (H, W) int32 geom id; -1 = background.
        body_segmentation: (H, W) int32 id of the body owning the geom; -1 = background.
        K: (3, 3) float64 intrinsics in pixels (OpenCV convention).
        world_from_camera: (4, 4) float64 pose of the OpenCV camera frame in world coordinates.
        camera: camera name.
        backend: ``"egl"``, ``"osmesa"``, ``"glfw"`` or ``"raycast"``.
        time: simulation time of the view, s.
    """

    rgb: np.ndarray
    depth: np.ndarray
    segmentation: np.ndarray
    body_segmentation: np.ndarray
    K: np.ndarray
    world_from_camera: np.ndarray
    camera: str
    backend: str
    time: float

    def instance_labels(self, by: str = "body") -> np.ndarray:
        """Ground-truth instance ids with 0 = background (the convention of perception labels).

        Args:
            by: ``"body"`` (id + 1 of the body owning the geom) or ``"geom"`` (geom id + 1).

        Returns:
            (H, W) int32.
        """
        if by not in ("body", "geom"):
            raise ValueError(f"by must be 'body' or 'geom', got {by!r}")
        ids = self.body_segmentation if by == "body" else self.segmentation
        return (ids + 1).astype(np.int32)

    def points(self) -> np.ndarray:
        """Back-project every pixel with depth > 0 to world coordinates.

        Returns:
            (H, W, 3) float64 world points in metres; NaN where depth is 0.
        """
        h, w = self.depth.shape
        u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
        z = self.depth.astype(np.float64)
        x = (u - self.K[0, 2]) / self.K[0, 0] * z
        y = (v - self.K[1, 2]) / self.K[1, 1] * z
        cam = np.stack([x, y, z], axis=-1)
        world = cam @ self.world_from_camera[:3, :3].T + self.world_from_camera[:3, 3]
        world[z <= 0] = np.nan
        return world


class Camera:
    """A named model camera that renders :class:`CameraFrame` views of an ``MjData``.

    Args:
        model: the compiled model.
        data: the simulation data to view (read, never stepped).
        camera: camera name (or id).
        width, height: image size in pixels.
        backend: one of :data:`BACKENDS` (see the module docstring).

    Raises:
        ValueError: unknown camera, bad size or backend, or a camera without ``fovy``
            (orthographic or sensor-size cameras are not supported).
        RenderBackendError: a GL backend was required and none could be opened.
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        data: mujoco.MjData,
        camera: str | int,
        *,
        width: int = 320,
        height: int = 240,
        backend: str = "auto",
    ) -> None:
        if backend not in BACKENDS:
            raise ValueError(f"backend {backend!r} unknown; expected one of {BACKENDS}")
        if isinstance(width, bool) or isinstance(height, bool) or int(width) < 1 or int(height) < 1:
            raise ValueError(f"image size must be positive ints, got width={width!r}, height={height!r}")
        names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_CAMERA, i) for i in range(model.ncam)]
        if isinstance(camera, str):
            if camera not in names:
                raise ValueError(f"unknown camera {camera!r}; the model's cameras are {names}")
            cam_id = names.index(camera)
        else:
            cam_id = int(camera)
            if not 0 <= cam_id < model.ncam:
                raise ValueError(f"camera id {cam_id} out of range [0, {model.ncam}); cameras: {names}")
        if int(model.cam_projection[cam_id]) != int(mujoco.mjtProjection.mjPROJ_PERSPECTIVE) or np.any(
            np.asarray(model.cam_sensorsize[cam_id]) > 0
        ):
            raise ValueError(
                f"camera {names[cam_id]!r} is orthographic or uses sensorsize; only fovy cameras are supported"
            )
        self.model, self.data = model, data
        self.name = names[cam_id] or str(cam_id)
        self.cam_id, self.width, self.height = cam_id, int(width), int(height)
        self.K = intrinsics(float(model.cam_fovy[cam_id]), self.width, self.height)
        self._renderer: GLRenderer | RayRenderer
        if backend == "raycast":
            self._renderer = RayRenderer(model, cam_id, self.K, self.width, self.height)
        else:
            order = gl_backend_order("auto" if backend == "gl" else backend)
            try:
                self._renderer = GLRenderer(model, cam_id, self.width, self.height, order)
            except RenderBackendError as err:
                if backend != "auto":
                    raise
                logger.warning("%s; falling back to the ray-cast camera (depth and flat colours)", err)
                self._renderer = RayRenderer(model, cam_id, self.K, self.width, self.height)

    @property
    def backend(self) -> str:
        """The backend in use: ``"egl"``, ``"osmesa"``, ``"glfw"`` or ``"raycast"``."""
        return self._renderer.backend

    def world_from_camera(self) -> np.ndarray:
        """(4, 4) pose of the OpenCV camera frame (x right, y down, z forward) in the world."""
        pose = np.eye(4)
        pose[:3, :3] = self.data.cam_xmat[self.cam_id].reshape(3, 3) @ _MJ_TO_CV
        pose[:3, 3] = self.data.cam_xpos[self.cam_id]
        return pose

    def render(self) -> CameraFrame:
        """Render the current state.

        Positions are first recomputed from ``qpos`` (``mj_kinematics``, ``mj_comPos``, ``mj_camlight``),
        because after ``mj_step`` they lag one substep behind; the physics state itself
        is not changed, so rendering does not perturb a babbling run.
        """
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_comPos(self.model, self.data)
        mujoco.mj_camlight(self.model, self.data)
        rgb, depth, geoms = self._renderer.render(self.data)
        bodies = np.where(geoms >= 0, np.asarray(self.model.geom_bodyid)[np.maximum(geoms, 0)], -1).astype(
            np.int32
        )
        return CameraFrame(
            rgb=rgb,
            depth=depth,
            segmentation=geoms,
            body_segmentation=bodies,
            K=self.K.copy(),
            world_from_camera=self.world_from_camera(),
            camera=self.name,
            backend=self.backend,
            time=float(self.data.time),
        )

    def close(self) -> None:
        """Free the renderer's resources (idempotent)."""
        self._renderer.close()

    def __enter__(self) -> Camera:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
