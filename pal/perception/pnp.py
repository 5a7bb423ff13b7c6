"""RGB-D PnP-RANSAC with a seeded generator, prior hypotheses, joint refinement and covariance.

:func:`pnp_ransac` (Eq. 4.15-4.16) estimates ``x_cam = R x_ref + t`` from 3-D reference points
and their 2-D observations, and the observations' depth where it exists. Its minimal samples
come from the caller's generator (OpenCV's ``solvePnPRansac`` draws from OpenCV's global
generator, so its result would depend on the calls made before it): each hypothesis is a
4-point AP3P solution, or, when the observed points have depth too, a vectorised 3-point
Kabsch fit of the 3-D pairs (cheap and many). The caller may add *prior hypotheses* (no motion,
constant velocity, the pose the camera motion predicts), scored like the others. A pair is an
inlier when it reprojects within ``reprojection_error`` pixels and, if the observation has
depth, its predicted depth is within ``depth_tolerance``.

The best hypothesis is refined by :func:`refine_pose`: Gauss-Newton on the joint residuals
``(u - û) / sigma_px``, ``(v - v̂) / sigma_px`` and, where the observation has depth,
``(z - ẑ) / sigma_z`` (sigma_z from the sensor's noise model), re-selecting the inliers
twice. Pixels constrain the pose across the view, depth along it: near, precise depth pins the
pose like a 3-D fit; far, noisy depth weighs little. Its covariance is ``s² (J^T J)^-1`` over
the perturbation ``R <- exp(w) R``, ``t <- t + d`` (rotation vector w in rad about the camera
origin, translation d of the reference origin in m), ``s²`` the residuals' variance factor.

:func:`reprojection_errors` scores any transform on pairs; :func:`pose_covariance` gives the
covariance of a 2-D fit alone, :func:`point_covariance` that of a 3-D fit.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from pal.perception.rigid import RigidFit, kabsch

__all__ = [
    "RgbdFit",
    "pnp_ransac",
    "point_covariance",
    "pose_covariance",
    "refine_pose",
    "reprojection_errors",
]


@dataclass(frozen=True, eq=False)
class RgbdFit(RigidFit):
    """A :class:`~pal.perception.rigid.RigidFit` with its covariance.

    Attributes:
        covariance: (6, 6) over (rotation vector rad, translation m), or None when singular.
        depth_inliers: inliers whose observation had depth.
    """

    covariance: np.ndarray | None = None
    depth_inliers: int = 0


def _project(R: np.ndarray, t: np.ndarray, obj: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (..., N, 2) and depths (..., N) of ``R obj + t``; R (..., 3, 3), t (..., 3)."""
    cam = np.matmul(obj, np.swapaxes(R, -1, -2)) + t[..., None, :]
    z = cam[..., 2]
    zs = np.where(z > 1e-9, z, 1e-9)
    u = K[0, 0] * cam[..., 0] / zs + K[0, 1] * cam[..., 1] / zs + K[0, 2]
    v = K[1, 1] * cam[..., 1] / zs + K[1, 2]
    return np.stack([u, v], axis=-1), z


def reprojection_errors(T: np.ndarray, obj: np.ndarray, img: np.ndarray, K: np.ndarray) -> np.ndarray:
    """(N,) pixel distance between ``project(T obj)`` and ``img``; inf behind the camera.

    Args:
        T: (4, 4) ``camera_from_reference``.
        obj: (N, 3) reference points, metres.
        img: (N, 2) observed pixels.
        K: (3, 3) intrinsics.
    """
    uv, z = _project(T[:3, :3], T[:3, 3], np.asarray(obj, float), np.asarray(K, float))
    err = np.linalg.norm(uv - img, axis=-1)
    return np.where(z > 1e-6, err, np.inf)


def _refine(
    obj: np.ndarray, img: np.ndarray, K: np.ndarray, R: np.ndarray, t: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    rvec, _ = cv2.Rodrigues(R)
    rvec, tvec = cv2.solvePnPRefineLM(obj, img, K, None, rvec, t.reshape(3, 1).copy())
    return cv2.Rodrigues(rvec)[0], tvec.ravel()


def pnp_ransac(
    object_points: np.ndarray,
    image_points: np.ndarray,
    K: np.ndarray,
    *,
    rng: np.random.Generator | int = 0,
    iterations: int = 200,
    reprojection_error: float = 6.0,
    confidence: float = 0.99,
    min_inliers: int = 6,
    image_points_3d: np.ndarray | None = None,
    hypotheses: Sequence[np.ndarray] = (),
    weights: np.ndarray | None = None,
    depth_tolerance: np.ndarray | float | None = None,
    depth_sigma: np.ndarray | float | None = None,
    prior_enough: float = 0.8,
) -> RgbdFit | None:
    """Seeded PnP-RANSAC (module docstring).

    Args:
        object_points: (N, 3) points in the reference frame, metres.
        image_points: (N, 2) their observed pixels in the current image.
        K: (3, 3) intrinsics of the current image.
        rng: generator (or seed) of the minimal samples.
        iterations: the most random hypotheses (adaptive below that).
        reprojection_error: inlier threshold, pixels.
        confidence: RANSAC confidence, in (0, 1).
        min_inliers: fewer inliers than this -> None.
        image_points_3d: optional (N, 3) current camera-frame points with NaN rows where the
            observation has no depth: 3-point Kabsch hypotheses are drawn from the pairs with
            depth.
        hypotheses: prior (4, 4) ``camera_from_reference`` transforms scored with the others.
        weights: optional (N,) non-negative weights of the pairs in the inlier score.
        depth_tolerance: largest depth disagreement of an inlier with depth, metres (scalar or
            (N,)); None: depth does not gate inliers.
        depth_sigma: depth noise of the observations, metres (scalar or (N,)), for the joint
            refinement; None: pixels only.
        prior_enough: a prior hypothesis whose inliers are at least this fraction of the pairs
            is refined without drawing random hypotheses (the prediction already fits).

    Returns:
        ``x_cam = R x_ref + t`` with inliers, the reprojection RMSE in pixels and the
        covariance, or None.
    """
    obj = np.ascontiguousarray(object_points, dtype=np.float64).reshape(-1, 3)
    img = np.ascontiguousarray(image_points, dtype=np.float64).reshape(-1, 2)
    K = np.asarray(K, dtype=np.float64)
    n = obj.shape[0]
    if img.shape[0] != n:
        raise ValueError(f"{n} object points but {img.shape[0]} image points")
    if n < max(6, min_inliers):
        return None
    gen = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    w = np.ones(n) if weights is None else np.asarray(weights, dtype=np.float64)
    live_z, tol = _depth_gate(n, image_points_3d, depth_tolerance)
    pool = _Hypotheses(obj, img, K, w, live_z, tol, reprojection_error, confidence, iterations)
    priors = [np.asarray(T, float) for T in hypotheses]
    pool.add([T[:3, :3] for T in priors], [T[:3, 3] for T in priors])
    T = _search(pool, gen, image_points_3d, prior_enough)
    if T is None:
        return None
    return refine_pose(
        obj,
        img,
        K,
        T,
        reprojection_error,
        min_inliers,
        live_z=live_z if depth_sigma is not None else None,
        depth_sigma=depth_sigma,
        depth_tolerance=tol,
    )


def _search(
    pool: _Hypotheses, gen: np.random.Generator, image_points_3d: np.ndarray | None, prior_enough: float
) -> np.ndarray | None:
    """The best hypothesis: the queued priors, then Kabsch and AP3P samples until confident.

    No random hypothesis is drawn when a prior explains ``prior_enough`` of the pairs.
    """
    obj, img, K, iterations = pool.obj, pool.img, pool.K, pool.iterations
    tried = 0
    needed = pool.score()
    if image_points_3d is not None and pool.fraction < prior_enough:
        live = np.asarray(image_points_3d, dtype=np.float64)
        tried = pool.add(*_kabsch_hypotheses(gen, obj, live, iterations))
        needed = pool.score()
    if pool.fraction >= prior_enough:
        needed = 0
    while tried < needed:
        tried += 1
        pool.add(*_ap3p_hypotheses(gen, obj, img, K, pool.reprojection_error))
        if len(pool.Rs) >= 32 or tried >= needed:
            needed = pool.score()
    return pool.best()


def _depth_gate(
    n: int, image_points_3d: np.ndarray | None, depth_tolerance: np.ndarray | float | None
) -> tuple[np.ndarray, np.ndarray]:
    """(N,) observed depths (NaN without) and (N,) depth tolerances of the inliers (inf: no gate)."""
    live_z = np.full(n, np.nan)
    if image_points_3d is not None:
        live_z = np.asarray(image_points_3d, dtype=np.float64)[:, 2]
    tol = np.full(n, np.inf)
    if depth_tolerance is not None:
        tol = np.where(np.isfinite(live_z), np.broadcast_to(np.asarray(depth_tolerance, float), (n,)), np.inf)
    return live_z, tol


def _kabsch_hypotheses(
    gen: np.random.Generator, obj: np.ndarray, live: np.ndarray, iterations: int
) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """3-point Kabsch fits of up to ``min(iterations, 96)`` samples of the pairs with depth."""
    both = np.flatnonzero(np.all(np.isfinite(live), axis=1))
    if both.size < 3:
        return [], []
    a = gen.integers(0, both.size, (min(iterations, 96), 3))
    ok = (a[:, 0] != a[:, 1]) & (a[:, 1] != a[:, 2]) & (a[:, 0] != a[:, 2])
    idx = both[a[ok]]
    if not idx.shape[0]:
        return [], []
    R3, t3 = kabsch(obj[idx], live[idx])
    return list(R3), list(t3)


def _ap3p_hypotheses(
    gen: np.random.Generator, obj: np.ndarray, img: np.ndarray, K: np.ndarray, reprojection_error: float
) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """The AP3P solutions of one random 4-point sample that reproject its fourth point within the threshold."""
    idx = gen.choice(obj.shape[0], size=4, replace=False)
    count, rvecs, tvecs = cv2.solveP3P(obj[idx[:3]], img[idx[:3]], K, None, flags=cv2.SOLVEPNP_AP3P)
    Rs, ts = [], []
    for rv, tv in zip(rvecs[:count], tvecs[:count], strict=True):
        R = cv2.Rodrigues(rv)[0]
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, tv.ravel()
        if reprojection_errors(T, obj[idx[3:]], img[idx[3:]], K)[0] < reprojection_error:
            Rs.append(R)
            ts.append(tv.ravel())
    return Rs, ts


class _Hypotheses:
    """Pending hypotheses and the best scored so far (weighted inlier count)."""

    def __init__(
        self,
        obj: np.ndarray,
        img: np.ndarray,
        K: np.ndarray,
        w: np.ndarray,
        live_z: np.ndarray,
        tol: np.ndarray,
        reprojection_error: float,
        confidence: float,
        iterations: int,
    ) -> None:
        self.obj, self.img, self.K, self.w, self.live_z, self.tol = obj, img, K, w, live_z, tol
        self.reprojection_error, self.confidence, self.iterations = reprojection_error, confidence, iterations
        self.Rs: list[np.ndarray] = []
        self.ts: list[np.ndarray] = []
        self.best_score = -1.0
        self.fit: tuple[np.ndarray, np.ndarray] | None = None
        self.fraction = 0.0

    def add(self, Rs: list[np.ndarray], ts: list[np.ndarray]) -> int:
        """Queue hypotheses; returns how many."""
        self.Rs.extend(Rs)
        self.ts.extend(ts)
        return len(Rs)

    def best(self) -> np.ndarray | None:
        """The best hypothesis so far as a (4, 4) transform, or None."""
        if self.fit is None:
            return None
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = self.fit
        return T

    def score(self) -> int:
        """Score the pending hypotheses; returns the hypotheses needed for ``confidence``."""
        if self.Rs:
            uv, z = _project(np.array(self.Rs), np.array(self.ts), self.obj, self.K)
            inl = (np.linalg.norm(uv - self.img, axis=-1) < self.reprojection_error) & (z > 1e-6)
            inl &= ~(np.abs(z - self.live_z) > self.tol)  # NaN (no depth) never disqualifies
            scores = inl @ self.w
            k = int(np.argmax(scores))
            if scores[k] > self.best_score:
                self.best_score, self.fit = float(scores[k]), (self.Rs[k], self.ts[k])
                self.fraction = float(inl[k].mean())
            self.Rs.clear()
            self.ts.clear()
        frac = self.fraction
        if frac >= 1.0:
            return 0
        if frac <= 0.0:
            return self.iterations
        return min(self.iterations, int(np.ceil(np.log(1 - self.confidence) / np.log(1 - frac**4))))


def _exp(w: np.ndarray) -> np.ndarray:
    return cv2.Rodrigues(np.asarray(w, dtype=np.float64).reshape(3, 1))[0]


def _gauss_newton(
    obj: np.ndarray,
    img: np.ndarray,
    K: np.ndarray,
    R: np.ndarray,
    t: np.ndarray,
    z_obs: np.ndarray,
    z_sigma: np.ndarray,
    sigma_px: float,
    steps: int = 4,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Gauss-Newton on the joint residuals (module docstring); NaN ``z_obs`` has no depth term.

    Returns:
        (R, t, (J^T J)^-1 or a NaN matrix when singular, chi² per degree of freedom).
    """
    fx, fy, s = K[0, 0], K[1, 1], K[0, 1]
    has_z = np.isfinite(z_obs)
    n, nz = obj.shape[0], int(has_z.sum())
    J, r = np.zeros((2 * n + nz, 6)), np.empty(2 * n + nz)
    zs_obs, zs_sigma = z_obs[has_z], z_sigma[has_z]
    JtJ = np.eye(6)
    chi2 = 0.0
    for _ in range(steps + 1):
        q = obj @ R.T
        p = q + t
        x, y, z = p[:, 0], p[:, 1], np.maximum(p[:, 2], 1e-6)
        r[:n] = (fx * x / z + s * y / z + K[0, 2] - img[:, 0]) / sigma_px
        r[n : 2 * n] = (fy * y / z + K[1, 2] - img[:, 1]) / sigma_px
        # d(u, v, z)/d(p): rows of the projection Jacobian; for the perturbation (w, d) of
        # p = exp(w) q + t + d with q = R x_ref, a row a . dp = (q x a) . w + a . d
        q0, q1, q2 = q[:, 0], q[:, 1], q[:, 2]
        du0, du1, du2 = fx / z / sigma_px, s / z / sigma_px, -(fx * x + s * y) / z**2 / sigma_px
        dv1, dv2 = fy / z / sigma_px, -fy * y / z**2 / sigma_px
        Ju, Jv = J[:n], J[n : 2 * n]
        Ju[:, 0], Ju[:, 1], Ju[:, 2] = q1 * du2 - q2 * du1, q2 * du0 - q0 * du2, q0 * du1 - q1 * du0
        Ju[:, 3], Ju[:, 4], Ju[:, 5] = du0, du1, du2
        Jv[:, 0], Jv[:, 1], Jv[:, 2] = q1 * dv2 - q2 * dv1, -q0 * dv2, q0 * dv1
        Jv[:, 4], Jv[:, 5] = dv1, dv2
        if nz:
            r[2 * n :] = (z[has_z] - zs_obs) / zs_sigma
            Jz = J[2 * n :]
            Jz[:, 0], Jz[:, 1], Jz[:, 5] = q1[has_z] / zs_sigma, -q0[has_z] / zs_sigma, 1.0 / zs_sigma
        JtJ = J.T @ J
        chi2 = float(r @ r) / max(r.size - 6, 1)
        if _ == steps:
            break
        delta = -np.linalg.solve(JtJ + 1e-9 * np.trace(JtJ) * np.eye(6), J.T @ r)
        R = _exp(delta[:3]) @ R
        t = t + delta[3:]
        if np.linalg.norm(delta) < 1e-10:
            break
    if np.linalg.cond(JtJ) > 1e12:
        return R, t, np.full((6, 6), np.nan), chi2
    return R, t, np.linalg.inv(JtJ), chi2


def refine_pose(
    obj: np.ndarray,
    img: np.ndarray,
    K: np.ndarray,
    T: np.ndarray,
    reprojection_error: float,
    min_inliers: int,
    *,
    live_z: np.ndarray | None = None,
    depth_sigma: np.ndarray | float | None = None,
    depth_tolerance: np.ndarray | float | None = None,
    sigma_px: float = 1.0,
) -> RgbdFit | None:
    """Refine ``T`` on its inliers by joint Gauss-Newton, twice, re-selecting the inliers.

    Args:
        obj: (N, 3) reference points, metres.
        img: (N, 2) observed pixels.
        K: (3, 3) intrinsics.
        T: (4, 4) initial ``camera_from_reference``.
        reprojection_error: inlier threshold, pixels.
        min_inliers: fewer inliers than this at any step -> None.
        live_z: optional (N,) observed depth, NaN where none, metres.
        depth_sigma: depth noise of the observations, metres (scalar or (N,)); needed with
            ``live_z``.
        depth_tolerance: largest depth disagreement of an inlier, metres (scalar or (N,)).
        sigma_px: pixel noise of the observations.
    """
    obj = np.ascontiguousarray(obj, dtype=np.float64)
    img = np.ascontiguousarray(img, dtype=np.float64)
    n = obj.shape[0]
    z_obs = np.full(n, np.nan) if live_z is None or depth_sigma is None else np.asarray(live_z, float)
    z_sig = np.broadcast_to(np.asarray(1.0 if depth_sigma is None else depth_sigma, float), (n,))
    tol = np.broadcast_to(np.asarray(np.inf if depth_tolerance is None else depth_tolerance, float), (n,))
    R, t = T[:3, :3].copy(), T[:3, 3].copy()

    def inliers_of(R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        M = np.eye(4)
        M[:3, :3], M[:3, 3] = R, t
        err = reprojection_errors(M, obj, img, K)
        z = obj @ R[2] + t[2]
        return (err < reprojection_error) & ~(np.abs(z - z_obs) > tol), err

    inliers, err = inliers_of(R, t)
    inv = np.full((6, 6), np.nan)
    chi2 = 1.0
    for _ in range(2):
        if inliers.sum() < max(min_inliers, 4):
            return None
        R, t, inv, chi2 = _gauss_newton(
            obj[inliers], img[inliers], K, R, t, z_obs[inliers], z_sig[inliers], sigma_px
        )
        inliers, err = inliers_of(R, t)
    if inliers.sum() < min_inliers:
        return None
    cov = None if not np.all(np.isfinite(inv)) else inv * max(chi2, 0.25)
    return RgbdFit(
        R,
        t,
        inliers,
        float(np.sqrt(np.mean(err[inliers] ** 2))),
        cov,
        int((inliers & np.isfinite(z_obs)).sum()),
    )


def pose_covariance(
    R: np.ndarray, t: np.ndarray, obj: np.ndarray, img: np.ndarray, K: np.ndarray, rmse: float
) -> np.ndarray | None:
    """(6, 6) covariance of (rotation vector [rad], translation [m]) of a PnP fit on its inliers.

    ``rmse² (J^T J)^-1`` with J the (2N, 6) Jacobian of the projections (OpenCV's
    ``projectPoints``); None when J^T J is singular (too few or degenerate points).
    """
    if obj.shape[0] < 3:
        return None
    rvec, _ = cv2.Rodrigues(np.asarray(R, float))
    _, jac = cv2.projectPoints(np.asarray(obj, float), rvec, np.asarray(t, float).reshape(3, 1), K, None)
    J = jac[:, :6]
    JtJ = J.T @ J
    if np.linalg.cond(JtJ) > 1e12:
        return None
    return max(rmse, 0.3) ** 2 * np.linalg.inv(JtJ)


def point_covariance(R: np.ndarray, src: np.ndarray, rmse: float) -> np.ndarray | None:
    """(6, 6) covariance of (rotation vector [rad], translation [m]) of a 3-D rigid fit.

    For ``dst = R src + t`` with isotropic residuals of ``rmse`` metres: ``rmse² (J^T J)^-1``
    with ``J_i = [-[R src_i]_x, I]`` (left perturbation of the rotation); None when singular.
    """
    p = np.asarray(src, float) @ np.asarray(R, float).T
    if p.shape[0] < 3:
        return None
    s = p.sum(axis=0)
    skew = np.array([[0.0, -s[2], s[1]], [s[2], 0.0, -s[0]], [-s[1], s[0], 0.0]])
    JtJ = np.zeros((6, 6))
    JtJ[:3, :3] = np.sum(p * p) * np.eye(3) - p.T @ p
    JtJ[:3, 3:] = skew
    JtJ[3:, :3] = -skew
    JtJ[3:, 3:] = p.shape[0] * np.eye(3)
    if np.linalg.cond(JtJ) > 1e12:
        return None
    return max(rmse, 1e-4) ** 2 * np.linalg.inv(JtJ)
