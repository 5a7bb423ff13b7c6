"""Robust support-plane fit: RANSAC on back-projected depth points, refined by least squares.

The plane is ``n . x + d = 0`` in the camera frame, with unit normal ``n`` oriented so the
camera (the origin) is on the positive side (``d > 0``). The signed distance
``n . x + d`` of a point is then its height above the plane, in metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Plane", "fit_plane_ransac", "plane_height", "refit_plane"]


@dataclass(frozen=True)
class Plane:
    """A plane and the support of its fit.

    Attributes:
        normal: (3,) unit normal, camera frame, pointing towards the camera side.
        offset: d in ``n . x + d = 0``, metres (> 0: the camera lies above the plane).
        inlier_fraction: fraction of the fitted points within the RANSAC threshold.
        num_points: number of points the fit used.
    """

    normal: np.ndarray
    offset: float
    inlier_fraction: float = 1.0
    num_points: int = 0

    def __post_init__(self) -> None:
        n = np.asarray(self.normal, dtype=np.float64)
        if n.shape != (3,) or not np.all(np.isfinite(n)) or not np.isfinite(self.offset):
            raise ValueError(
                f"plane normal {n} / offset {self.offset} must be a finite (3,) vector and scalar"
            )
        norm = np.linalg.norm(n)
        if norm < 1e-9:
            raise ValueError("plane normal has zero length")
        n, d = n / norm, float(self.offset) / norm
        if d < 0:
            n, d = -n, -d
        object.__setattr__(self, "normal", n)
        object.__setattr__(self, "offset", d)

    def height(self, points: np.ndarray) -> np.ndarray:
        """Signed height of (..., 3) camera-frame points above the plane, metres."""
        return np.asarray(points) @ self.normal + self.offset


def refit_plane(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Total-least-squares plane ``(normal (3,), offset)`` through (N >= 3, 3) points."""
    centre = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - centre, full_matrices=False)
    n = vt[-1]
    return n, -float(n @ centre)


def fit_plane_ransac(
    points: np.ndarray,
    threshold: float,
    rng: np.random.Generator,
    *,
    iterations: int = 100,
    refinements: int = 2,
) -> Plane:
    """Fit the dominant plane of a point cloud.

    All ``iterations`` minimal samples are scored at once (vectorised); the best one is refined
    by total least squares on its inliers ``refinements`` times.

    Args:
        points: (N, 3) float camera-frame points, metres, N >= 3.
        threshold: inlier distance, metres (> 0).
        rng: source of the random minimal samples.
        iterations: number of RANSAC hypotheses.
        refinements: least-squares refits on the inliers.

    Raises:
        ValueError: fewer than 3 points, non-finite points, or a non-positive threshold.
    """
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3 or pts.shape[0] < 3:
        raise ValueError(f"points has shape {pts.shape}, expected (N, 3) with N >= 3")
    if not np.all(np.isfinite(pts)):
        raise ValueError("points contain NaN/inf")
    if not threshold > 0:
        raise ValueError(f"threshold is {threshold}, expected > 0 metres")
    idx = rng.integers(0, pts.shape[0], size=(iterations, 3))
    p0, p1, p2 = pts[idx[:, 0]], pts[idx[:, 1]], pts[idx[:, 2]]
    normals = np.cross(p1 - p0, p2 - p0)
    norms = np.linalg.norm(normals, axis=1)
    ok = norms > 1e-12
    if not ok.any():
        raise ValueError("every RANSAC sample was degenerate (collinear or repeated points)")
    normals, p0 = normals[ok] / norms[ok, None], p0[ok]
    offsets = -np.einsum("ij,ij->i", normals, p0)
    counts = (np.abs(pts @ normals.T + offsets) < threshold).sum(axis=0)
    best = int(np.argmax(counts))
    n, d = normals[best], float(offsets[best])
    inliers = np.abs(pts @ n + d) < threshold
    for _ in range(refinements):
        if inliers.sum() < 3:
            break
        n, d = refit_plane(pts[inliers])
        inliers = np.abs(pts @ n + d) < threshold
    return Plane(n, d, float(inliers.mean()), int(pts.shape[0]))


def plane_height(depth: np.ndarray, K: np.ndarray, plane: Plane) -> np.ndarray:
    """Per-pixel signed height above ``plane`` of the back-projected depth image.

    Uses ``n . x + d = z * (n . ray(u, v)) + d`` with the ray coefficients built as an outer
    sum, so the cost is two operations per pixel.

    Args:
        depth: (H, W) float32, metres (0 = invalid: such pixels get height ``d``, the
            camera's own height, and the caller must mask them out).
        K: (3, 3) intrinsics.
        plane: the plane ``n . x + d = 0`` in the camera frame.

    Returns:
        (H, W) float32 heights, metres.
    """
    h, w = depth.shape
    n = plane.normal
    fx, s, cx, fy, cy = K[0, 0], K[0, 1], K[0, 2], K[1, 1], K[1, 2]
    ys = (np.arange(h) - cy) / fy
    # x = (u - cx - s*y) / fx: the skew term depends on the row only
    col = (n[0] * (np.arange(w) - cx) / fx).astype(np.float32)
    row = (n[1] * ys - n[0] * s * ys / fx + n[2]).astype(np.float32)
    coeff = row[:, None] + col[None, :]
    return depth * coeff + np.float32(plane.offset)
