"""Ray-cast camera: depth and segmentation with ``mujoco.mj_multiRay``, no OpenGL needed.

Each pixel (u, v) casts one ray through its centre. With intrinsics K (pixel centres at
integer coordinates, see :func:`pal.sim.camera.intrinsics`), the ray direction in the MuJoCo
camera frame (x right, y up, looking along -z) is ``((u - cx)/fx, -(v - cy)/fy, -1)``; the
hit distance along the unit ray times its cosine to the optical axis is the depth, so it
is directly comparable to the GL depth buffer. Colours are flat per geom (the geom's
material or rgba colour, no lighting).
"""

from __future__ import annotations

import mujoco
import numpy as np

__all__ = ["RayRenderer", "geom_colours"]

#: Colour of pixels whose ray hits nothing (uint8 RGB).
BACKGROUND_RGB = np.array([0, 0, 0], np.uint8)


def geom_colours(model: mujoco.MjModel) -> np.ndarray:
    """Flat colour of every geom: its material's rgba if it has one, else its rgba.

    Returns:
        (ngeom + 1, 3) uint8; the last row is the background colour.
    """
    rgba = np.array(model.geom_rgba, dtype=np.float64)
    mat = np.asarray(model.geom_matid)
    has_mat = mat >= 0
    if np.any(has_mat):
        rgba[has_mat] = model.mat_rgba[mat[has_mat]]
    colours = np.clip(np.round(rgba[:, :3] * 255), 0, 255).astype(np.uint8)
    return np.vstack([colours, BACKGROUND_RGB[None]])


class RayRenderer:
    """Ray-casts one fixed camera.

    Args:
        model: the compiled model.
        cam_id: camera id.
        K: (3, 3) intrinsics in pixels.
        width, height: image size in pixels.
    """

    def __init__(self, model: mujoco.MjModel, cam_id: int, K: np.ndarray, width: int, height: int) -> None:
        self.model, self.cam_id, self.width, self.height = model, cam_id, width, height
        self.backend = "raycast"
        fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
        u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
        dirs = np.stack([(u - cx) / fx, -(v - cy) / fy, -np.ones_like(u)], axis=-1).reshape(-1, 3)
        norm = np.linalg.norm(dirs, axis=1)
        self._dirs = dirs / norm[:, None]  # unit rays, camera frame
        self._cos = 1.0 / norm  # cosine between each ray and the optical axis
        self._vec = np.empty(dirs.size, np.float64)
        self._geom = np.empty(width * height, np.int32)
        self._dist = np.empty(width * height, np.float64)
        self._groups = np.asarray(mujoco.MjvOption().geomgroup, dtype=np.uint8)
        self._colours = geom_colours(model)
        self._cutoff = float(model.vis.map.zfar * model.stat.extent)

    def render(self, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Ray-cast the current ``data`` (kinematics must be up to date).

        Returns:
            ``rgb`` (H, W, 3) uint8 flat colours; ``depth`` (H, W) float32 metres along the
            optical axis, 0 where nothing was hit; ``geom_ids`` (H, W) int32, -1 = background.
        """
        m = self.model
        rot = data.cam_xmat[self.cam_id].reshape(3, 3)
        self._vec[:] = (self._dirs @ rot.T).ravel()
        mujoco.mj_multiRay(
            m,
            data,
            np.array(data.cam_xpos[self.cam_id]),
            self._vec,
            self._groups,
            1,
            -1,
            self._geom,
            self._dist,
            None,
            self.width * self.height,
            self._cutoff,
        )
        hit = (self._geom >= 0) & (self._dist >= 0)
        geom_ids = np.where(hit, self._geom, -1).astype(np.int32)
        depth = np.where(hit, self._dist * self._cos, 0.0).astype(np.float32)
        rgb = self._colours[geom_ids]  # index -1 is the background row
        shape = (self.height, self.width)
        return rgb.reshape(*shape, 3), depth.reshape(shape), geom_ids.reshape(shape)

    def close(self) -> None:
        """Nothing to free; present for symmetry with the GL renderer."""
