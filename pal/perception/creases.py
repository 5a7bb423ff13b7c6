"""Surface normals from depth and the concave creases where touching objects meet.

Two objects that touch meet along a *concave* crease: a can standing against a box, the top
of a short box against the front of a taller one. The faces of one object meet at *convex*
edges (a box's corners, a can's rim). This is the local-convexity criterion of LCCP (Stein et
al., CVPR 2014): for two surface points ``x1``, ``x2`` with normals ``n1``, ``n2`` (towards
the camera), the surface between them is concave when

    c = (n1 - n2) . (x1 - x2) / |x1 - x2|  <  -tau,   and   (n1 - n2) . (x1 - x2) < -k sigma_z

(on a convex surface every point lies below the other's tangent plane, so ``n1 . (x1 - x2)
>= 0 >= n2 . (x1 - x2)`` and ``c >= 0``; on a plane ``c = 0``). A crease of angle ``phi``
between the normals, seen across, gives ``c = -2 sin(phi / 2)``. The second condition keeps
the noise of the normals out: ``(n1 - n2) . (x1 - x2)`` is a depth (how far the crease lies
behind the two tangent planes), and its noise is a few depth-noise sigmas whatever the
distance between the points.

:func:`surface_normals` smooths the depth over a ``window`` (invalid pixels do not count),
back-projects it, and takes the normal from central differences ``step`` pixels apart.
:func:`creases` marks the pixel between every pair ``step`` pixels apart (along rows,
columns and both diagonals) whose surface is concave (or convex) by more than ``tau``, where both normals
are defined and the two points lie within ``max_gap`` of each other in depth (a larger step
is a depth discontinuity, cut elsewhere). The whole image is processed at once.
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["creases", "normal_change", "surface_normals"]


def surface_normals(
    depth: np.ndarray, K: np.ndarray, window: int, step: int
) -> tuple[np.ndarray, np.ndarray]:
    """Smoothed points and unit normals of a depth image.

    Args:
        depth: (H, W) float32 metres, 0 = invalid.
        K: (3, 3) intrinsics, pixels (of this image: shift the principal point for a crop).
        window: box-filter width for the depth, pixels (odd, >= 1).
        step: half the distance of the central differences, pixels (>= 1).

    Returns:
        points (3, H, W) float32 metres and normals (3, H, W) float32 unit vectors pointing
        towards the camera (x, y, z planes); normals are 0 where the depth (or a difference's
        end) is invalid.
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
    pts = np.stack([z * u[None, :], z * v[:, None], z])
    s = step
    du = np.zeros_like(pts)
    dv = np.zeros_like(pts)
    du[:, :, s:-s] = pts[:, :, 2 * s :] - pts[:, :, : -2 * s]
    dv[:, s:-s] = pts[:, 2 * s :] - pts[:, : -2 * s]
    ok = z > 0
    good = ok.copy()
    good[:, :s] = good[:, -s:] = False
    good[:s] = good[-s:] = False
    good[:, s:-s] &= ok[:, 2 * s :] & ok[:, : -2 * s]
    good[s:-s] &= ok[2 * s :] & ok[: -2 * s]
    n = np.stack(
        [
            du[1] * dv[2] - du[2] * dv[1],
            du[2] * dv[0] - du[0] * dv[2],
            du[0] * dv[1] - du[1] * dv[0],
        ]
    )
    norm = np.sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2])
    good &= norm > 0
    # unit length, pointing towards the camera (the origin): n . p < 0
    sign = np.where(n[0] * pts[0] + n[1] * pts[1] + n[2] * pts[2] > 0, -1.0, 1.0).astype(np.float32)
    n *= np.where(good, sign / np.maximum(norm, 1e-12), 0.0)
    return pts, n


_DIRECTIONS = ((0, 1), (1, 0), (1, 1), (1, -1))


def _pairs(a: np.ndarray, dv: int, du: int, s: int) -> tuple[np.ndarray, np.ndarray, tuple[slice, slice]]:
    """Views of ``a`` (..., H, W) at ``p - s d`` and ``p + s d`` for the pixels p where both exist, and p's slice."""
    h, w = a.shape[-2:]
    ov, ou = s * dv, s * du
    rows = slice(ov, h - ov)
    cols = slice(abs(ou), w - abs(ou))
    first = a[..., rows.start - ov : rows.stop - ov, cols.start - ou : cols.stop - ou]
    second = a[..., rows.start + ov : rows.stop + ov, cols.start + ou : cols.stop + ou]
    return first, second, (rows, cols)


def creases(
    points: np.ndarray, normals: np.ndarray, step: int, tau: float, max_gap: np.ndarray, min_depth: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Concave and convex creases: pixels between two surface points ``step`` px apart.

    Args:
        points: (3, H, W) metres, from :func:`surface_normals`.
        normals: (3, H, W) unit normals (0 = undefined).
        step: half the distance between the two points, pixels.
        tau: threshold of ``|c|`` (module docstring), in (0, 2).
        max_gap: (H, W) float32 metres: the two points' depths differ by less than this.
        min_depth: (H, W) float32 metres: the crease is also deeper (or higher) than this,
            ``|(n1 - n2) . (x1 - x2)| > min_depth`` (a few depth-noise sigmas: noisy normals
            of far surfaces do not make creases).

    Returns:
        (H, W) bool concave creases (where touching objects meet) and (H, W) bool convex
        creases (the edges of one object).
    """
    if not 0 < tau < 2:
        raise ValueError(f"tau is {tau}, expected in (0, 2)")
    concave = np.zeros(points.shape[1:], dtype=bool)
    convex = np.zeros(points.shape[1:], dtype=bool)
    defined = normals[2] != 0
    for dv, du in _DIRECTIONS:
        p1, p2, sl = _pairs(points, dv, du, step)
        n1, n2, _ = _pairs(normals, dv, du, step)
        d1, d2, _ = _pairs(defined, dv, du, step)
        d = p1 - p2
        c = ((n1 - n2) * d).sum(axis=0)
        bound = np.maximum(tau * np.sqrt((d * d).sum(axis=0)), min_depth[sl])
        ok = d1 & d2 & (np.abs(d[2]) < max_gap[sl])
        concave[sl] |= ok & (c < -bound)
        convex[sl] |= ok & (c > bound)
    return concave, convex


def normal_change(normals: np.ndarray, step: int) -> np.ndarray:
    """(H, W) float32: the largest ``1 - n1 . n2`` over pairs ``step`` px apart around each pixel (0 if undefined)."""
    out = np.zeros(normals.shape[1:], dtype=np.float32)
    defined = normals[2] != 0
    for dv, du in _DIRECTIONS:
        n1, n2, sl = _pairs(normals, dv, du, step)
        d1, d2, _ = _pairs(defined, dv, du, step)
        change = np.where(d1 & d2, 1.0 - (n1 * n2).sum(axis=0), 0.0)
        np.maximum(out[sl], change, out=out[sl])
    return out
