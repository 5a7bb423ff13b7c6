"""The terms of the dense fit (:mod:`pal.perception.icp`): projective correspondences and grey levels.

:class:`LiveSurface` looks up live points and normals at the pixels where the moved model
projects; :func:`associate` pairs the model with it under a pose (KinectFusion-style projective
association); :class:`Photometric` gives the whitened grey-level residuals of the model points
and their Jacobian rows over the step ``(w, d)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from pal.perception.frames import RGBDFrame, backproject
from pal.perception.masks import Mask
from pal.perception.quantiles import median

__all__ = [
    "LiveSurface",
    "Match",
    "Photometric",
    "associate",
    "bilinear",
    "cross",
    "smooth",
    "surface_normals",
]


def smooth(gray: np.ndarray, sigma: float) -> np.ndarray:
    """(h, w) float32 grey levels smoothed by a Gaussian of ``sigma`` pixels (0: none)."""
    g = np.asarray(gray, dtype=np.float32)
    return cv2.GaussianBlur(g, (0, 0), sigma) if sigma > 0 else g


def bilinear(img: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Bilinear samples (N,) of (h, w) ``img``, or (N, C) of (h, w, C), at float pixels (u, v).

    The pixels (N,) must lie in [0, w-1) x [0, h-1).
    """
    u0, v0 = np.floor(u).astype(np.int64), np.floor(v).astype(np.int64)
    a, b = u - u0, v - v0
    if img.ndim == 3:
        a, b = a[:, None], b[:, None]
    return (
        img[v0, u0] * (1 - a) * (1 - b)
        + img[v0, u0 + 1] * a * (1 - b)
        + img[v0 + 1, u0] * (1 - a) * b
        + img[v0 + 1, u0 + 1] * a * b
    )


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross product of (N, 3) arrays (cheaper than ``np.cross`` for small N)."""
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[:, 0] = a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
    out[:, 1] = a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
    out[:, 2] = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    return out


class LiveSurface:
    """Live points and normals in a mask's box, computed only at the pixels looked up.

    With ``grow`` > 0 the box is grown by that many pixels and any valid depth in it counts,
    in the mask or not.
    """

    def __init__(self, frame: RGBDFrame, mask: Mask, max_jump: float, baseline: int, grow: int = 0) -> None:
        self.baseline = baseline
        H, W = frame.depth.shape
        bx0, by0, bx1, by1 = mask.bbox
        self.x0, self.y0 = max(0, bx0 - grow), max(0, by0 - grow)
        x1, y1 = min(W, bx1 + grow), min(H, by1 + grow)
        self.z = frame.depth[self.y0 : y1, self.x0 : x1]
        self.valid = (mask.region(self.x0, self.y0, x1, y1) if grow == 0 else np.ones(self.z.shape, bool)) & (
            self.z > 0
        )
        self.h, self.w = self.z.shape
        self.K = frame.K
        self.max_jump = max_jump

    def lookup(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(ok (N,), points (N, 3), unit normals (N, 3) facing the camera) at crop pixels (u, v)."""
        b = self.baseline
        ok = (u >= b) & (v >= b) & (u < self.w - b) & (v < self.h - b)
        ok[ok] = self.valid[v[ok], u[ok]]
        good, P, n = surface_normals(self.z, u[ok], v[ok], (self.x0, self.y0), self.K, b, self.max_jump)
        keep = np.zeros(len(ok), dtype=bool)
        keep[np.flatnonzero(ok)[good]] = True
        return keep, P, n


def surface_normals(
    z: np.ndarray,
    u: np.ndarray,
    v: np.ndarray,
    origin: tuple[int, int],
    K: np.ndarray,
    b: int,
    max_jump: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points and camera-facing unit normals from depth differences over +-``b`` pixels.

    Args:
        z: (h, w) depth, metres: the frame, or a crop whose top-left pixel is ``origin``.
        u: (N,) int pixel columns in ``z``, at least ``b`` from its border.
        v: (N,) int pixel rows in ``z``, the same.
        origin: (x0, y0) of ``z`` in the full frame, pixels.
        K: (3, 3) full-frame intrinsics.
        b: the baseline, pixels.
        max_jump: largest depth step across the baseline, per pixel and metre of depth.

    Returns:
        (good (N,): all four neighbours have depth, no step and a normal; points (P, 3) and
        unit normals (P, 3) of the good pixels, metres).
    """
    zc, zr, zl, zd, zu = z[v, u], z[v, u + b], z[v, u - b], z[v + b, u], z[v - b, u]
    # the centre and its four neighbours lifted at once: (5, N, 3)
    uu = np.stack([u, u + b, u - b, u, u]) + origin[0]
    vv = np.stack([v, v, v, v + b, v - b]) + origin[1]
    L = backproject(uu, vv, np.stack([zc, zr, zl, zd, zu]), K)
    P, dx, dy = L[0], L[1] - L[2], L[3] - L[4]
    n = cross(dx, dy)
    norm = np.linalg.norm(n, axis=1)
    good = (
        (zr > 0)
        & (zl > 0)
        & (zd > 0)
        & (zu > 0)
        & (np.abs(dx[:, 2]) < max_jump * b * zc)
        & (np.abs(dy[:, 2]) < max_jump * b * zc)
        & (norm > 1e-12)
    )
    n = n / np.where(norm > 1e-12, norm, 1.0)[:, None]
    n = np.where((np.sum(n * P, axis=1) > 0)[:, None], -n, n)  # face the camera
    return good, P[good], n[good]


class Photometric:
    """The photometric term: grey-level residuals of model points in the live image, whitened.

    The live grey levels are smoothed over the live mask's box grown by ``4 + grow`` pixels.
    """

    def __init__(
        self, frame: RGBDFrame, mask: Mask, model_gray: np.ndarray, grow: int, blur_sigma: float, sigma: float
    ) -> None:
        pad = 4 + grow
        H, Wd = frame.depth.shape
        self.x0, self.y0 = max(0, mask.bbox[0] - pad), max(0, mask.bbox[1] - pad)
        gx1, gy1 = min(Wd, mask.bbox[2] + pad), min(H, mask.bbox[3] + pad)
        self.img = smooth(frame.gray()[self.y0 : gy1, self.x0 : gx1], blur_sigma)
        self.gu = cv2.Sobel(self.img, cv2.CV_32F, 1, 0, ksize=3) / 8.0
        self.gv = cv2.Sobel(self.img, cv2.CV_32F, 0, 1, ksize=3) / 8.0
        self.levels = np.dstack([self.img, self.gu, self.gv])  # sampled together: (h, w, 3)
        self.K = frame.K
        self.model_gray = model_gray
        self.sigma = float(sigma)

    def __call__(self, sel: np.ndarray, y: np.ndarray, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Residuals (P,) and Jacobian rows (P, 6) of model points ``sel`` (rotated ``y``, moved ``X``)."""
        img, K = self.img, self.K
        z = X[:, 2]
        u = K[0, 0] * X[:, 0] / z + K[0, 1] * X[:, 1] / z + K[0, 2] - self.x0
        v = K[1, 1] * X[:, 1] / z + K[1, 2] - self.y0
        ok = (u >= 0) & (v >= 0) & (u < img.shape[1] - 1) & (v < img.shape[0] - 1)
        u, v, z, y, X, sel = u[ok], v[ok], z[ok], y[ok], X[ok], sel[ok]
        sampled = bilinear(self.levels, u, v)
        r = sampled[:, 0] - self.model_gray[sel]
        r = r - median(r) if len(r) else r
        g = sampled[:, 1:]
        # d(u, v)/dX for the pinhole, then dX/d(w, d) = [-[y]x, I]
        du = np.stack([K[0, 0] / z, np.zeros_like(z), -K[0, 0] * X[:, 0] / z**2], axis=1)
        dv = np.stack([np.zeros_like(z), K[1, 1] / z, -K[1, 1] * X[:, 1] / z**2], axis=1)
        gX = g[:, :1] * du + g[:, 1:] * dv
        J = np.concatenate([cross(y, gX), gX], axis=1)
        return r / self.sigma, J / self.sigma


@dataclass(frozen=True, eq=False)
class Match:
    """Projective correspondences of the model under a pose (:func:`associate`).

    ``idx`` are the matched model points, ``y`` their rotated and ``X`` moved coordinates, ``q``
    and ``n`` the live points and normals; ``u``, ``v`` (crop pixels), ``inside`` (in the box)
    and ``z`` (depth) are over all model points.
    """

    idx: np.ndarray
    y: np.ndarray
    X: np.ndarray
    q: np.ndarray
    n: np.ndarray
    u: np.ndarray
    v: np.ndarray
    inside: np.ndarray
    z: np.ndarray


def associate(model: np.ndarray, R: np.ndarray, t: np.ndarray, live: LiveSurface) -> Match:
    """Move the model by (R, t), project it and pair each point with the live surface at its pixel."""
    K = live.K
    y = model @ R.T
    X = y + t
    z = X[:, 2]
    zs = np.where(z > 1e-6, z, 1e-6)
    u = np.rint(K[0, 0] * X[:, 0] / zs + K[0, 1] * X[:, 1] / zs + K[0, 2]).astype(np.int64) - live.x0
    v = np.rint(K[1, 1] * X[:, 1] / zs + K[1, 2]).astype(np.int64) - live.y0
    inside = (z > 1e-6) & (u >= 0) & (v >= 0) & (u < live.w) & (v < live.h)
    idx = np.flatnonzero(inside)
    good, q, n = live.lookup(u[idx], v[idx])
    idx = idx[good]
    return Match(idx, y[idx], X[idx], q, n, u, v, inside, z)
