"""Surface normals from depth and the concave creases where touching objects meet.

Two objects that touch meet along a *concave* crease: a can standing against a box, the top
of a short box against the front of a taller one. The faces of one object meet at *convex*
edges (a box's corners, a can's rim). This is the local-convexity criterion of LCCP (Stein et
al., CVPR 2014): for two surface points ``x1``, ``x2`` with normals ``n1``, ``n2`` (towards
the camera), the surface between them is concave when

    c = (n1 - n2) . (x1 - x2) / |x1 - x2|  <  -tau

(on a convex surface every point lies below the other's tangent plane, so ``n1 . (x1 - x2)
>= 0 >= n2 . (x1 - x2)`` and ``c >= 0``; on a plane ``c = 0``). A crease of angle ``phi``
between the normals, seen across, gives ``c = -2 sin(phi / 2)``.

:func:`surface_normals` smooths the depth over a ``window`` (invalid pixels do not count),
back-projects it, and takes the normal from central differences ``step`` pixels apart.
:func:`concave_creases` marks the pixel between every pair ``step`` pixels apart (along rows,
columns and both diagonals) whose surface is concave by more than ``tau``, where both normals
are defined and the two points lie within ``max_gap`` of each other in depth (a larger step
is a depth discontinuity, cut elsewhere). The whole image is processed at once.
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["concave_creases", "normal_change", "surface_normals"]


def surface_normals(depth: np.ndarray, K: np.ndarray, window: int, step: int) -> tuple[np.ndarray, np.ndarray]:
    """Smoothed points and unit normals of a depth image.

    Args:
        depth: (H, W) float32 metres, 0 = invalid.
        K: (3, 3) intrinsics, pixels.
        window: box-filter width for the depth, pixels (odd, >= 1).
        step: half the distance of the central differences, pixels (>= 1).

    Returns:
        points (H, W, 3) float32 metres and normals (H, W, 3) float32 unit vectors pointing
        towards the camera; both 0 where the depth (or a difference's end) is invalid.
    """
    if depth.ndim != 2:
        raise ValueError(f"depth has shape {depth.shape}, expected (H, W)")
    if window < 1 or window % 2 == 0 or step < 1:
        raise ValueError(f"window {window} must be odd and >= 1, step {step} >= 1 (pixels)")
    h, w = depth.shape
    valid = (depth > 0).astype(np.float32)
    z = cv2.blur(depth * valid, (window, window)) / np.maximum(cv2.blur(valid, (window, window)), 1e-6)
    z = np.where(depth > 0, z, 0.0).astype(np.float32)
    fx, fy, cx, cy = float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])
    u = (np.arange(w, dtype=np.float32) - np.float32(cx)) / np.float32(fx)
    v = (np.arange(h, dtype=np.float32) - np.float32(cy)) / np.float32(fy)
    pts = np.stack([z * u[None, :], z * v[:, None], z], axis=-1)
    s = step
    du = np.zeros_like(pts)
    dv = np.zeros_like(pts)
    du[:, s:-s] = pts[:, 2 * s :] - pts[:, : -2 * s]
    dv[s:-s] = pts[2 * s :] - pts[: -2 * s]
    ok = z > 0
    ok_u = np.zeros_like(ok)
    ok_v = np.zeros_like(ok)
    ok_u[:, s:-s] = ok[:, 2 * s :] & ok[:, : -2 * s]
    ok_v[s:-s] = ok[2 * s :] & ok[: -2 * s]
    n = np.cross(du, dv)
    norm = np.linalg.norm(n, axis=-1)
    good = ok & ok_u & ok_v & (norm > 0)
    n = np.where(good[..., None], n / np.maximum(norm, 1e-12)[..., None], 0.0)
    flip = (n * pts).sum(axis=-1) > 0  # point the normal towards the camera (the origin)
    n[flip] = -n[flip]
    return pts, n.astype(np.float32)


_DIRECTIONS = ((0, 1), (1, 0), (1, 1), (1, -1))


def _pairs(a: np.ndarray, dv: int, du: int, s: int) -> tuple[np.ndarray, np.ndarray, tuple[slice, slice]]:
    """Views of ``a`` at ``p - s d`` and ``p + s d`` for the pixels p where both exist, and p's slice."""
    h, w = a.shape[:2]
    ov, ou = s * dv, s * du
    rows = slice(ov, h - ov)
    cols = slice(abs(ou), w - abs(ou))
    first = a[rows.start - ov : rows.stop - ov, cols.start - ou : cols.stop - ou]
    second = a[rows.start + ov : rows.stop + ov, cols.start + ou : cols.stop + ou]
    return first, second, (rows, cols)


def concave_creases(
    points: np.ndarray, normals: np.ndarray, step: int, tau: float, max_gap: np.ndarray
) -> np.ndarray:
    """(H, W) bool: pixels between two surface points ``step`` px apart whose surface is concave.

    Args:
        points: (H, W, 3) metres, from :func:`surface_normals`.
        normals: (H, W, 3) unit normals (0 = undefined).
        step: half the distance between the two points, pixels.
        tau: concavity threshold of ``c`` (module docstring), in (0, 2).
        max_gap: (H, W) float32 metres: the two points' depths differ by less than this.
    """
    if not 0 < tau < 2:
        raise ValueError(f"tau is {tau}, expected in (0, 2)")
    out = np.zeros(points.shape[:2], dtype=bool)
    defined = np.any(normals != 0, axis=-1)
    for dv, du in _DIRECTIONS:
        p1, p2, sl = _pairs(points, dv, du, step)
        n1, n2, _ = _pairs(normals, dv, du, step)
        d1, d2, _ = _pairs(defined, dv, du, step)
        d = p1 - p2
        dist = np.linalg.norm(d, axis=-1)
        c = ((n1 - n2) * d).sum(axis=-1) / np.maximum(dist, 1e-9)
        near = np.abs(d[..., 2]) < max_gap[sl]
        out[sl] |= d1 & d2 & near & (c < -tau)
    return out


def normal_change(normals: np.ndarray, step: int) -> np.ndarray:
    """(H, W) float32: the largest ``1 - n1 . n2`` over pairs ``step`` px apart around each pixel (0 if undefined)."""
    out = np.zeros(normals.shape[:2], dtype=np.float32)
    defined = np.any(normals != 0, axis=-1)
    for dv, du in _DIRECTIONS:
        n1, n2, sl = _pairs(normals, dv, du, step)
        d1, d2, _ = _pairs(defined, dv, du, step)
        change = np.where(d1 & d2, 1.0 - (n1 * n2).sum(axis=-1), 0.0)
        np.maximum(out[sl], change, out=out[sl])
    return out
