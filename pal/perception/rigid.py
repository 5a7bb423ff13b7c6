"""Rigid registration: Kabsch/Umeyama in RANSAC, with PnP-RANSAC as the fallback.

Kabsch/Umeyama (Eq. 4.15) runs inside RANSAC with a threshold in metres; PnP-RANSAC
(Eq. 4.16) is the fallback when 3-D/3-D correspondences are too few.

The proof of concept fitted a 3-D *affine* map with a 3-unit threshold on metre-scale points
(rejecting nothing) and projected it onto a rotation. Here every hypothesis is a proper rigid
transform from three correspondences, scored with a metric threshold (default 1.5 cm).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

__all__ = ["RigidFit", "kabsch", "pnp_ransac", "ransac_rigid", "to_homogeneous"]


@dataclass(frozen=True)
class RigidFit:
    """x_dst ≈ R x_src + t.

    Attributes:
        R: (3, 3) rotation (det +1).
        t: (3,) translation, metres.
        inliers: (N,) bool.
        rmse: root-mean-square residual over the inliers (metres for 3-D fits, pixels for PnP).
    """

    R: np.ndarray
    t: np.ndarray
    inliers: np.ndarray
    rmse: float

    @property
    def num_inliers(self) -> int:
        """Number of inlier correspondences."""
        return int(self.inliers.sum())

    def matrix(self) -> np.ndarray:
        """The fit as a (4, 4) homogeneous transform."""
        return to_homogeneous(self.R, self.t)


def to_homogeneous(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(4, 4) transform from a rotation and a translation."""
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def kabsch(
    src: np.ndarray, dst: np.ndarray, weights: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares rotation and translation with ``dst ≈ R src + t`` (Umeyama 1991, no scale).

    Batched: ``src`` and ``dst`` may be (..., N, 3); returns (..., 3, 3) and (..., 3).
    Reflections are corrected so that det(R) = +1.
    """
    src, dst = np.asarray(src, dtype=np.float64), np.asarray(dst, dtype=np.float64)
    if src.shape != dst.shape or src.shape[-1] != 3 or src.shape[-2] < 3:
        raise ValueError(f"src {src.shape} and dst {dst.shape} must both be (..., N >= 3, 3)")
    if weights is None:
        w = np.full(src.shape[:-1], 1.0 / src.shape[-2])
    else:
        w = np.asarray(weights, dtype=np.float64)
        w = w / w.sum(axis=-1, keepdims=True)
    mu_s = np.einsum("...n,...nk->...k", w, src)
    mu_d = np.einsum("...n,...nk->...k", w, dst)
    cov = np.einsum("...n,...ni,...nj->...ij", w, dst - mu_d[..., None, :], src - mu_s[..., None, :])
    u, _, vt = np.linalg.svd(cov)
    d = np.sign(np.linalg.det(u @ vt))
    d = np.where(d == 0, 1.0, d)
    fix = np.ones((*src.shape[:-2], 3))
    fix[..., 2] = d
    R = (u * fix[..., None, :]) @ vt
    t = mu_d - np.einsum("...ij,...j->...i", R, mu_s)
    return R, t


def ransac_rigid(
    src: np.ndarray,
    dst: np.ndarray,
    threshold: float,
    rng: np.random.Generator,
    *,
    iterations: int = 128,
    min_inliers: int = 6,
) -> RigidFit | None:
    """Robust rigid fit: vectorised 3-point Kabsch hypotheses, best inlier count, Kabsch refits.

    Args:
        src: (N, 3) source points, metres, N >= 3.
        dst: (N, 3) corresponding destination points, metres.
        threshold: inlier residual, metres.
        rng: source of the minimal samples.
        iterations: hypotheses.
        min_inliers: fewer inliers than this -> None.

    Returns:
        the fit, or None when no hypothesis reaches ``min_inliers``.
    """
    src, dst = np.asarray(src, dtype=np.float64), np.asarray(dst, dtype=np.float64)
    n = src.shape[0]
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3:
        raise ValueError(f"src {src.shape} and dst {dst.shape} must both be (N, 3)")
    if not threshold > 0:
        raise ValueError(f"threshold is {threshold}, expected > 0 metres")
    if n < max(3, min_inliers):
        return None
    # three distinct indices per hypothesis
    idx = _distinct_triples(rng, n, iterations)
    R, t = kabsch(src[idx], dst[idx])
    diff = src @ R.transpose(0, 2, 1) + (t[:, None, :] - dst[None])  # (h, n, 3) residual vectors
    res = np.sqrt(np.einsum("hni,hni->hn", diff, diff))
    counts = (res < threshold).sum(axis=1)
    best = int(np.argmax(counts))
    if counts[best] < min_inliers:
        return None
    inliers = res[best] < threshold
    Rb, tb = R[best], t[best]
    for _ in range(3):
        Rb, tb = kabsch(src[inliers], dst[inliers])
        r = np.linalg.norm(src @ Rb.T + tb - dst, axis=1)
        new = r < threshold
        if new.sum() < min_inliers:
            break
        if np.array_equal(new, inliers):
            break
        inliers = new
    r = np.linalg.norm(src @ Rb.T + tb - dst, axis=1)
    inliers = r < threshold
    if inliers.sum() < min_inliers:
        return None
    return RigidFit(Rb, tb, inliers, float(np.sqrt(np.mean(r[inliers] ** 2))))


def _distinct_triples(rng: np.random.Generator, n: int, k: int) -> np.ndarray:
    """(k, 3) random index triples, the three indices of each row distinct (n >= 3)."""
    a = rng.integers(0, n, k)
    b = (a + rng.integers(1, n, k)) % n
    c = rng.integers(0, n - 2, k)
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    c = c + (c >= lo) + ((c + (c >= lo)) >= hi)
    return np.stack([a, b, c], axis=1)


def pnp_ransac(
    object_points: np.ndarray,
    image_points: np.ndarray,
    K: np.ndarray,
    *,
    iterations: int = 100,
    reprojection_error: float = 6.0,
    confidence: float = 0.99,
    min_inliers: int = 6,
) -> RigidFit | None:
    """PnP-RANSAC (OpenCV, EPnP hypotheses, iterative refinement on the inliers).

    Args:
        object_points: (N, 3) points in the reference frame, metres.
        image_points: (N, 2) their observed pixels in the current image.
        K: (3, 3) intrinsics of the current image.
        iterations: RANSAC hypotheses.
        reprojection_error: inlier threshold, pixels.
        confidence: RANSAC confidence, in (0, 1).
        min_inliers: fewer inliers than this -> None.

    Returns:
        ``x_cam = R x_ref + t`` with inliers and the reprojection RMSE in pixels, or None.
    """
    obj = np.ascontiguousarray(object_points, dtype=np.float64).reshape(-1, 3)
    img = np.ascontiguousarray(image_points, dtype=np.float64).reshape(-1, 2)
    if obj.shape[0] != img.shape[0]:
        raise ValueError(f"{obj.shape[0]} object points but {img.shape[0]} image points")
    if obj.shape[0] < max(6, min_inliers):
        return None
    ok, rvec, tvec, idx = cv2.solvePnPRansac(
        obj,
        img,
        np.asarray(K, dtype=np.float64),
        None,
        iterationsCount=iterations,
        reprojectionError=reprojection_error,
        confidence=confidence,
        flags=cv2.SOLVEPNP_EPNP,
    )
    if not ok or idx is None or len(idx) < min_inliers:
        return None
    inliers = np.zeros(obj.shape[0], dtype=bool)
    inliers[idx.ravel()] = True
    rvec, tvec = cv2.solvePnPRefineLM(
        obj[inliers], img[inliers], np.asarray(K, dtype=np.float64), None, rvec, tvec
    )
    R, _ = cv2.Rodrigues(rvec)
    t = tvec.ravel()
    cam = obj @ R.T + t
    if np.any(cam[inliers, 2] <= 0):
        return None
    uvw = cam @ np.asarray(K, dtype=np.float64).T
    proj = uvw[:, :2] / np.maximum(uvw[:, 2:3], 1e-9)
    err = np.linalg.norm(proj - img, axis=1)
    inliers = inliers & (err < reprojection_error)
    if inliers.sum() < min_inliers:
        return None
    return RigidFit(R, t, inliers, float(np.sqrt(np.mean(err[inliers] ** 2))))
