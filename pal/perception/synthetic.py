"""Analytic RGB-D rendering of textured boxes and matte spheres on a support plane.

A pinhole ray caster in numpy: every frame has exact depth, exact instance labels and exact
object poses, so each perception stage can be checked against a known answer without MuJoCo or
a GPU (tests, examples, and timing of the pipeline on its own).

Conventions are those of :class:`pal.perception.frames.RGBDFrame`: OpenCV camera frame, depth
in metres along the optical axis (0 where a ray hits nothing), labels 0 = background/plane.
Objects are placed with ``camera_from_object`` (4, 4) transforms; :func:`table_pose` builds the
camera-from-table transform of an oblique overhead camera, so objects can be placed on the
table in table coordinates (x, y on the table, z up).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pal.perception.frames import RGBDFrame

__all__ = ["Box", "Sphere", "SyntheticCamera", "pinhole", "table_pose"]


def pinhole(width: int, height: int, fovy_deg: float = 45.0) -> np.ndarray:
    """Intrinsics with square pixels and the principal point at the image centre."""
    f = height / (2.0 * math.tan(math.radians(fovy_deg) / 2.0))
    return np.array([[f, 0.0, (width - 1) / 2.0], [0.0, f, (height - 1) / 2.0], [0.0, 0.0, 1.0]])


def table_pose(distance: float = 0.8, pitch_deg: float = 50.0) -> np.ndarray:
    """camera_from_table (4, 4) looking at the table origin from ``distance`` metres.

    The optical axis is tilted ``pitch_deg`` from the table normal (0 = straight down). Table
    z points up, table y points away from the camera.
    """
    p = math.radians(pitch_deg)
    # table axes expressed in the camera frame (x right, y down, z forward)
    x_t = np.array([1.0, 0.0, 0.0])
    z_t = np.array([0.0, -math.sin(p), -math.cos(p)])  # up, towards the camera
    y_t = np.cross(z_t, x_t)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2] = x_t, y_t, z_t
    T[:3, 3] = [0.0, 0.0, distance]
    return T


@dataclass(frozen=True, eq=False)
class Box:
    """A box with a blocky random colour texture on each face.

    Attributes:
        size: (3,) full extents along the object's x, y, z, metres.
        pose: (4, 4) camera_from_object (object origin at the box centre).
        label: instance id (>= 1).
        seed: texture seed.
        cells: texture cells along each face edge.
    """

    size: tuple[float, float, float]
    pose: np.ndarray
    label: int = 1
    seed: int = 0
    cells: int = 8


@dataclass(frozen=True, eq=False)
class Sphere:
    """A uniformly coloured, Lambert-shaded sphere (few local features by construction)."""

    radius: float
    center: np.ndarray
    color: tuple[int, int, int] = (200, 40, 40)
    label: int = 1


def _face_textures(seed: int, cells: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.integers(20, 236, size=(6, cells, cells, 3)).astype(np.float32)


class SyntheticCamera:
    """Renders :class:`RGBDFrame` s of objects on a plane.

    Args:
        width, height: image size, pixels.
        K: intrinsics; default :func:`pinhole` with 45° vertical field of view.
        table: camera_from_table of the support plane (its z = 0 plane); None: no plane.
        table_color: RGB of the table (a faint texture is added).
    """

    def __init__(
        self,
        width: int = 160,
        height: int = 120,
        K: np.ndarray | None = None,
        table: np.ndarray | None = None,
        table_color: tuple[int, int, int] = (150, 140, 120),
    ) -> None:
        self.width, self.height = int(width), int(height)
        self.K = pinhole(self.width, self.height) if K is None else np.asarray(K, dtype=np.float64)
        self.table = table_pose() if table is None else np.asarray(table, dtype=np.float64)
        self.table_color = np.asarray(table_color, dtype=np.float32)
        v, u = np.mgrid[0 : self.height, 0 : self.width].astype(np.float64)
        Kinv = np.linalg.inv(self.K)
        # (3, N) ray directions with z = 1, so the ray parameter t is the depth
        self._rays = Kinv @ np.stack([u.ravel(), v.ravel(), np.ones(u.size)])
        self._ray_norm2 = (self._rays**2).sum(axis=0)
        self._textures: dict[tuple[int, int], np.ndarray] = {}

    def render(
        self,
        objects: Sequence[Box | Sphere],
        timestamp: float = 0.0,
        *,
        depth_noise: float = 0.0,
        rng: np.random.Generator | None = None,
    ) -> RGBDFrame:
        """Ray-cast one frame.

        Args:
            objects: boxes and spheres.
            timestamp: s.
            depth_noise: std of Gaussian depth noise, metres (needs ``rng``).
            rng: generator for the depth noise.
        """
        H, W = self.height, self.width
        d = self._rays  # (3, N), rows x, y, 1
        depth = np.full(d.shape[1], np.inf)
        rgb = np.zeros((d.shape[1], 3), dtype=np.float32)
        labels = np.zeros(d.shape[1], dtype=np.int32)
        # table plane: n . (t d) = n . c
        n, c = self.table[:3, 2], self.table[:3, 3]
        denom = n @ d
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (n @ c) / denom
        hit = np.isfinite(t) & (t > 0)
        depth[hit] = t[hit]
        ex, ey = self.table[:3, 0], self.table[:3, 1]
        th = t[hit]
        lx = (ex @ d[:, hit]) * th - ex @ c
        ly = (ey @ d[:, hit]) * th - ey @ c
        speck = ((np.floor(lx / 0.05) + np.floor(ly / 0.05)) % 2) * 6.0
        rgb[hit] = self.table_color + speck[:, None].astype(np.float32)
        for obj in objects:
            if isinstance(obj, Box):
                self._box(obj, d, depth, rgb, labels)
            else:
                self._sphere(obj, d, depth, rgb, labels)
        valid = np.isfinite(depth)
        z = np.where(valid, depth, 0.0)
        if depth_noise > 0:
            if rng is None:
                raise ValueError("depth_noise > 0 needs an rng")
            z = np.where(valid, z + rng.normal(0.0, depth_noise, z.shape), 0.0).clip(0.0, None)
        return RGBDFrame(
            rgb=np.clip(rgb, 0, 255).astype(np.uint8).reshape(H, W, 3),
            depth=z.astype(np.float32).reshape(H, W),
            K=self.K,
            timestamp=timestamp,
            labels=labels.reshape(H, W),
        )

    def _box(self, box: Box, d: np.ndarray, depth: np.ndarray, rgb: np.ndarray, labels: np.ndarray) -> None:
        R, c = box.pose[:3, :3], box.pose[:3, 3]
        h = np.asarray(box.size, dtype=np.float64) / 2.0
        o = -R.T @ c
        # coarse reject: rays outside the bounding sphere's cone cannot hit
        rad = float(np.linalg.norm(h))
        cand = self._sphere_hits(c, rad, d)
        if cand.size == 0:
            return
        db = R.T @ d[:, cand]  # (3, M) rays in the box frame
        with np.errstate(divide="ignore", invalid="ignore"):
            t1 = (-h[:, None] - o[:, None]) / db
            t2 = (h[:, None] - o[:, None]) / db
        tnear, tfar = np.minimum(t1, t2), np.maximum(t1, t2)
        tnear = np.where(np.isnan(tnear), -np.inf, tnear)
        tfar = np.where(np.isnan(tfar), np.inf, tfar)
        t_in, t_out = tnear.max(axis=0), tfar.min(axis=0)
        hit = (t_out >= t_in) & (t_in > 0) & (t_in < depth[cand])
        if not hit.any():
            return
        idx = cand[hit]
        th = t_in[hit]
        axis = tnear[:, hit].argmax(axis=0)
        p = o[:, None] + db[:, hit] * th
        cols = np.arange(idx.size)
        sign = np.sign(p[axis, cols])
        face = axis * 2 + (sign > 0)
        a1, a2 = (axis + 1) % 3, (axis + 2) % 3
        s = (p[a1, cols] / (2 * h[a1]) + 0.5).clip(0, 1 - 1e-9)
        q = (p[a2, cols] / (2 * h[a2]) + 0.5).clip(0, 1 - 1e-9)
        key = (box.seed, box.cells)
        if key not in self._textures:
            self._textures[key] = _face_textures(box.seed, box.cells)
        tex = self._textures[key]
        color = tex[face, (q * box.cells).astype(np.int64), (s * box.cells).astype(np.int64)]
        normal_cam = R[:, axis] * sign  # (3, M)
        dh = d[:, idx]
        shade = 0.55 + 0.45 * np.abs((normal_cam * dh).sum(axis=0) / np.sqrt((dh * dh).sum(axis=0)))
        depth[idx], labels[idx] = th, box.label
        rgb[idx] = color * shade[:, None].astype(np.float32)

    def _sphere_hits(self, c: np.ndarray, radius: float, d: np.ndarray) -> np.ndarray:
        """Indices of rays that intersect the sphere (c, radius) in front of the camera."""
        a = self._ray_norm2
        b = c @ d
        disc = b * b - a * (c @ c - radius**2)
        return np.flatnonzero((disc >= 0) & (b > 0))

    def _sphere(
        self, sph: Sphere, d: np.ndarray, depth: np.ndarray, rgb: np.ndarray, labels: np.ndarray
    ) -> None:
        c = np.asarray(sph.center, dtype=np.float64)
        cand = self._sphere_hits(c, sph.radius, d)
        if cand.size == 0:
            return
        dc = d[:, cand]
        a = self._ray_norm2[cand]
        b = c @ dc
        t = (b - np.sqrt(np.maximum(b * b - a * (c @ c - sph.radius**2), 0.0))) / a
        hit = (t > 0) & (t < depth[cand])
        if not hit.any():
            return
        idx = cand[hit]
        th = t[hit]
        dh = dc[:, hit]
        nrm = (dh * th - c[:, None]) / sph.radius
        shade = 0.35 + 0.65 * np.abs((nrm * dh).sum(axis=0) / np.sqrt(a[hit]))
        depth[idx], labels[idx] = th, sph.label
        rgb[idx] = np.asarray(sph.color, dtype=np.float32) * shade[:, None].astype(np.float32)
