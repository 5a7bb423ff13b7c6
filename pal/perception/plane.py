"""Robust plane fits: adaptive RANSAC on back-projected depth points, refined by least squares.

The plane is ``n . x + d = 0`` in the camera frame, with unit normal ``n`` oriented so the
camera (the origin) is on the positive side (``d > 0``). The signed distance
``n . x + d`` of a point is then its height above the plane, in metres.

RANSAC is adaptive: hypotheses are drawn in batches until ``N = log(1 - p) / log(1 - w³)``
of them have been tried, where ``w`` is the best inlier fraction so far and ``p`` the wanted
confidence (0.999), between ``min_iterations`` and ``max_iterations``. The samples come from a
generator the caller owns (a seed gives the same plane). With enough hypotheses the best plane
no longer depends on the seed: the least-squares refinement on the inliers converges to the
same plane from any good sample. Inlier thresholds may be per point (depth-dependent, see
:mod:`pal.perception.noise`). :func:`extract_planes` peels off the dominant planes one after
another.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Plane", "extract_planes", "fit_plane_ransac", "plane_height", "refit_plane"]


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


def refit_plane(points: np.ndarray, weights: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """Total-least-squares plane ``(normal (3,), offset)`` through (N >= 3, 3) points.

    Args:
        points: (N, 3) metres.
        weights: optional (N,) non-negative weights (e.g. 1 / sigma² of each point's depth).
    """
    if weights is None:
        centre = points.mean(axis=0)
        _, _, vt = np.linalg.svd(points - centre, full_matrices=False)
    else:
        w = np.asarray(weights, dtype=np.float64) / np.sum(weights)
        centre = w @ points
        _, _, vt = np.linalg.svd((points - centre) * np.sqrt(w)[:, None], full_matrices=False)
    n = vt[-1]
    return n, -float(n @ centre)


def _inliers(pts: np.ndarray, n: np.ndarray, d: float, thr: np.ndarray | float) -> np.ndarray:
    return np.abs(pts @ n + d) < thr


def fit_plane_ransac(
    points: np.ndarray,
    threshold: float | np.ndarray,
    rng: np.random.Generator,
    *,
    iterations: int = 1000,
    min_iterations: int = 64,
    confidence: float = 0.999,
    refinements: int = 2,
    score_points: int = 500,
) -> Plane:
    """Fit the dominant plane of a point cloud (adaptive RANSAC, module docstring).

    Hypotheses are scored in vectorised batches of 64; after each batch the number of
    hypotheses needed for ``confidence`` is recomputed from the best inlier fraction. The best
    hypothesis is refined by total least squares on its inliers ``refinements`` times, each
    inlier weighted by ``1 / threshold²`` (with per-point thresholds from a noise model, far
    and noisy points weigh less).

    Args:
        points: (N, 3) float camera-frame points, metres, N >= 3.
        threshold: inlier distance, metres (> 0): a scalar or (N,) per point.
        rng: source of the random minimal samples.
        iterations: the most hypotheses (the adaptive count is capped here).
        min_iterations: the fewest hypotheses.
        confidence: probability that at least one sample is all inliers, in (0, 1).
        refinements: least-squares refits on the inliers.
        score_points: hypotheses are scored on a random subset of at most this many points
            (the refinement uses them all).

    Raises:
        ValueError: fewer than 3 points, non-finite points, or a non-positive threshold.
    """
    pts, thr = _checked(points, threshold, confidence)
    score = np.arange(pts.shape[0])
    if pts.shape[0] > score_points:
        score = np.sort(rng.choice(pts.shape[0], size=score_points, replace=False))
    spts = pts[score]
    thr_col = thr if thr.ndim == 0 else thr[score][:, None]
    best_count, best_n, best_d = -1, None, 0.0
    needed, tried, batch = max(min_iterations, 1), 0, 64
    while tried < min(needed, iterations):
        normals, offsets = _sample_planes(pts, rng, batch)
        tried += batch
        if normals is None:
            continue
        dist = spts @ normals.T
        dist += offsets
        counts = np.count_nonzero(np.abs(dist, out=dist) < thr_col, axis=0)
        k = int(np.argmax(counts))
        if counts[k] > best_count:
            best_count, best_n, best_d = int(counts[k]), normals[k], float(offsets[k])
            w = best_count / spts.shape[0]
            if w >= 1.0:
                needed = tried
            elif w > 0:
                needed = max(min_iterations, int(np.ceil(np.log(1 - confidence) / np.log(1 - w**3))))
    if best_n is None:
        raise ValueError("every RANSAC sample was degenerate (collinear or repeated points)")
    return _refine(pts, thr, best_n, best_d, refinements)


def _checked(
    points: np.ndarray, threshold: float | np.ndarray, confidence: float
) -> tuple[np.ndarray, np.ndarray]:
    """The points (N, 3) and thresholds (scalar or (N,)) as float64, checked (:func:`fit_plane_ransac`)."""
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3 or pts.shape[0] < 3:
        raise ValueError(f"points has shape {pts.shape}, expected (N, 3) with N >= 3")
    if not np.all(np.isfinite(pts)):
        raise ValueError("points contain NaN/inf")
    thr = np.asarray(threshold, dtype=np.float64)
    if thr.shape not in ((), (pts.shape[0],)) or not np.all(thr > 0):
        raise ValueError(f"threshold must be > 0 metres, a scalar or one per point; got shape {thr.shape}")
    if not 0 < confidence < 1:
        raise ValueError(f"confidence is {confidence}, expected in (0, 1)")
    return pts, thr


def _sample_planes(
    pts: np.ndarray, rng: np.random.Generator, batch: int
) -> tuple[np.ndarray, np.ndarray] | tuple[None, None]:
    """Planes through ``batch`` random point triples: unit normals (B, 3) and offsets (B,).

    Degenerate triples are left out; (None, None) when all are.
    """
    idx = rng.integers(0, pts.shape[0], size=(batch, 3))
    p0 = pts[idx[:, 0]]
    a, b = pts[idx[:, 1]] - p0, pts[idx[:, 2]] - p0
    normals = np.stack(
        [
            a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1],
            a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
            a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0],
        ],
        axis=1,
    )
    norms = np.linalg.norm(normals, axis=1)
    ok = norms > 1e-12
    if not ok.any():
        return None, None
    normals, p0 = normals[ok] / norms[ok, None], p0[ok]
    return normals, -np.einsum("ij,ij->i", normals, p0)


def _refine(pts: np.ndarray, thr: np.ndarray, n: np.ndarray, d: float, refinements: int) -> Plane:
    """Refit the plane ``(n, d)`` on its inliers ``refinements`` times, weighted by ``1 / thr²`` per point."""
    inliers = _inliers(pts, n, d, thr)
    weights = None if thr.ndim == 0 else 1.0 / thr**2
    for _ in range(refinements):
        if inliers.sum() < 3:
            break
        n, d = refit_plane(pts[inliers], None if weights is None else weights[inliers])
        inliers = _inliers(pts, n, d, thr)
    return Plane(n, d, float(inliers.mean()), int(pts.shape[0]))


def extract_planes(
    points: np.ndarray,
    threshold: float | np.ndarray,
    rng: np.random.Generator,
    *,
    max_planes: int = 4,
    min_fraction: float = 0.08,
    iterations: int = 500,
) -> list[tuple[Plane, np.ndarray]]:
    """The dominant planes of a point cloud, peeled off one after another.

    Each round fits :func:`fit_plane_ransac` to the points not yet explained and removes its
    inliers; it stops after ``max_planes`` planes, or when a plane would explain fewer than
    ``min_fraction`` of all the points, or fewer than 3 points are left.

    Args:
        points: (N, 3) camera-frame points, metres.
        threshold: inlier distance, metres: a scalar or (N,) per point.
        rng: source of the random samples.
        max_planes: the most planes returned.
        min_fraction: a plane must hold at least this fraction of all N points.
        iterations: RANSAC hypotheses per plane, at most.

    Returns:
        ``(plane, inliers)`` pairs, largest first; ``inliers`` is an (N,) bool mask over
        ``points`` (disjoint between planes). ``plane.inlier_fraction`` is relative to all N.
    """
    pts = np.asarray(points, dtype=np.float64)
    thr = np.broadcast_to(np.asarray(threshold, dtype=np.float64), (pts.shape[0],))
    free = np.ones(pts.shape[0], dtype=bool)
    out: list[tuple[Plane, np.ndarray]] = []
    while len(out) < max_planes and free.sum() >= max(3, min_fraction * pts.shape[0]):
        rest = np.flatnonzero(free)
        plane = fit_plane_ransac(pts[rest], thr[rest], rng, iterations=iterations)
        inl = np.zeros(pts.shape[0], dtype=bool)
        inl[rest] = _inliers(pts[rest], plane.normal, plane.offset, thr[rest])
        if inl.sum() < max(3, min_fraction * pts.shape[0]):
            break
        out.append((Plane(plane.normal, plane.offset, float(inl.mean()), int(pts.shape[0])), inl))
        free &= ~inl
    return out


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
