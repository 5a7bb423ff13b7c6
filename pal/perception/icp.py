"""Dense object pose: point-to-plane ICP plus photometric alignment of a snapshot on the live RGB-D.

Objects with too few matched features (small, far or textureless: a chair, a cushion, a can
in shadow) still have depth. :func:`icp_fit` aligns the object's surface from one of its
snapshots (points ``x`` in the canonical object frame, sampled on a pixel grid of the
snapshot's mask) with the live depth inside the live mask, starting from a predicted pose
``T0 = camera_from_object`` (the camera's motion applied to the last estimate, or the last
estimate). Correspondences are projective (each model point is moved by the current pose,
projected with ``K``, and paired with the live point ``q`` and live normal ``n`` at that pixel,
as in KinectFusion), so a step costs O(model points) without a search tree. Each step solves the
linearised point-to-plane least squares::

    min_{w, d}  sum_i rho( n_i . (exp(w) R x_i + t + d - q_i) / sigma_z(z_i) )

             + sum_i rho( (I_live(pi(exp(w) R x_i + t + d)) - I_snap(x_i) - b) / sigma_I )

(``rho`` Huber, ``sigma_z`` the sensor's depth noise, :mod:`pal.perception.noise`; the second,
photometric, sum runs over the depth-agreeing points when grey levels are given: ``I`` are
Gaussian-smoothed grey levels, ``b`` the median brightness change, ``sigma_I`` grey levels), then
``R <- exp(w) R``, ``t <- t + d``; the correspondence gate shrinks from ``gate`` to
``3 sigma_z + tolerance`` once the steps settle (or half-way). Depth pins the pose across a
curved surface; texture pins the slides that depth cannot see (along a plane, about a
cylinder's axis). The fit's covariance is ``s^2 (J^T J)^-1`` over (w, d) — the convention of :mod:`pal.perception.pnp`, so the same
conditioning check applies — inflated by ``(correlation_px / grid step)^2`` when the samples are
closer than the sensor's noise correlation length (neighbouring depth readings of a structured
light sensor are not independent, and treating them as such would overstate the precision).

**Trust.** Depth alone does not pin a pose on flat or rotationally symmetric surfaces: ICP
then slides along them and stays wherever it started. The fit reports the *condition number*
of the normal equations of its depth terms (the ratio of the largest to the smallest singular
value; the photometric terms are left out, since shading on a smooth one-colour ball looks
like texture but does not turn with it, and would invent an orientation), with
rotations scaled by the points' RMS radius about their centroid (Gelfand et al.,
"Geometrically stable sampling for the ICP algorithm", 3DIM 2003): a large one means some
motion is unobservable, and the caller rejects the pose. The live normals are taken over
+-``normal_px`` pixels. The fit also reports how many model points that land on valid live
depth agree with it (``agree``) and how many claim a surface where the sensor sees farther (``free_space``
violations, the evidence that the object is not there).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from pal.checks import check_float, check_int
from pal.perception.frames import RGBDFrame, backproject
from pal.perception.masks import Mask
from pal.perception.noise import DepthNoise
from pal.perception.quantiles import median

__all__ = ["IcpConfig", "IcpFit", "geometric_condition", "icp_fit", "surface_points"]


@dataclass(frozen=True)
class IcpConfig:
    """Depth-only pose fitting (module docstring).

    Attributes:
        max_points: model points sampled from the snapshot's mask (a regular pixel grid).
        iterations: Gauss-Newton steps at most.
        gate: first correspondence gate, metres (the prediction's expected error).
        tolerance: final gate beyond ``3 sigma_z``, metres.
        min_points: fewest agreeing correspondences of an accepted fit.
        min_agreement: fewest agreeing model points per model point on valid live depth inside
            the live mask or in front of it (free-space violations count against it).
        max_condition: largest geometric condition number of an accepted fit.
        max_rmse_sigma: largest RMS point-to-plane residual of an accepted fit, in units of the
            sensor's sigma_z.
        photometric_sigma: grey-level noise of the photometric residuals; None: depth only.
        blur_sigma: Gaussian smoothing of the grey levels, pixels.
        correlation_px: noise correlation length of the depth sensor, pixels (covariance
            inflation, module docstring).
        normal_px: live normals are cross products of depth differences over +-this many
            pixels (a wide baseline sees through the steps of quantised depth, whose
            neighbouring-pixel normals would show structure a smooth surface does not have).
        grow_px: live pixels within this many pixels (at 640 columns) of the live mask's box
            may match too, in or out of the mask, where their depth agrees: a segment that lost
            part of the object (a hole, a split) leaves that part's depth where the model
            expects it (0: inside the live mask only).
        max_rotation_std_deg: largest rotation standard deviation of an accepted fit, deg ...
        max_translation_std: ... and translation standard deviation, metres (stricter than the
            feature fits' conditioning check: a dense fit is accepted only when it is precise).
    """

    max_points: int = 160
    iterations: int = 10
    gate: float = 0.05
    tolerance: float = 0.005
    min_points: int = 80
    min_agreement: float = 0.6
    max_condition: float = 6.0
    max_rmse_sigma: float = 2.5
    photometric_sigma: float | None = 6.0
    blur_sigma: float = 1.0
    correlation_px: float = 4.0
    normal_px: int = 3
    grow_px: int = 15
    max_rotation_std_deg: float = 1.5
    max_translation_std: float = 0.01

    def __post_init__(self) -> None:
        check_int("max_points", self.max_points, minimum=20)
        check_int("iterations", self.iterations)
        check_int("min_points", self.min_points, minimum=6)
        check_float("gate", self.gate, 0.0, 1.0, open_low=True)
        check_float("tolerance", self.tolerance, 0.0, 0.1)
        check_float("min_agreement", self.min_agreement, 0.0, 1.0)
        check_float("max_condition", self.max_condition, 1.0)
        check_float("max_rmse_sigma", self.max_rmse_sigma, 0.0, open_low=True)
        if self.photometric_sigma is not None:
            check_float("photometric_sigma", self.photometric_sigma, 0.0, open_low=True)
        check_float("blur_sigma", self.blur_sigma, 0.0)
        check_float("correlation_px", self.correlation_px, 0.0)
        check_int("normal_px", self.normal_px)
        check_int("grow_px", self.grow_px, minimum=0)
        check_float("max_rotation_std_deg", self.max_rotation_std_deg, 0.0, open_low=True)
        check_float("max_translation_std", self.max_translation_std, 0.0, open_low=True)


@dataclass(frozen=True, eq=False)
class IcpFit:
    """The result of :func:`icp_fit`.

    Attributes:
        T: (4, 4) ``camera_from_object``.
        points: correspondences within the final gate.
        visible: model points landing on valid live depth inside the live mask (or, with
            ``grow_px``, near it).
        agree: of those, within the final gate.
        free_space: model points in front of which the sensor sees farther than the gate
            (it measured through where the fit puts the surface).
        rmse: RMS point-to-plane residual of the correspondences, metres.
        rmse_sigma: the same in units of sigma_z.
        condition: condition number of the depth terms' normal equations (module docstring);
            inf when singular.
        photometric: photometric residuals used (0: depth only).
        covariance: (6, 6) over (rotation vector rad, translation m), or None when singular.
        iterations: steps taken.
    """

    T: np.ndarray
    points: int
    visible: int
    agree: int
    free_space: int
    rmse: float
    rmse_sigma: float
    condition: float
    covariance: np.ndarray | None
    iterations: int
    photometric: int = 0

    @property
    def agreement(self) -> float:
        """The agreeing fraction: ``agree / (visible + free_space)``, 0 without any."""
        n = self.visible + self.free_space
        return self.agree / n if n else 0.0


def surface_points(
    depth: np.ndarray,
    mask: np.ndarray,
    origin: tuple[int, int],
    K: np.ndarray,
    max_points: int,
    depth_range: tuple[float, float] = (0.1, 6.0),
    gray: np.ndarray | None = None,
    blur_sigma: float = 1.0,
) -> tuple[np.ndarray, np.ndarray | None, int]:
    """Camera-frame points of a mask crop on a regular grid of at most about ``max_points``.

    Args:
        depth: (h, w) float32 metres, a crop.
        mask: (h, w) bool.
        origin: (x0, y0) of the crop in the full frame, pixels.
        K: (3, 3) full-frame intrinsics.
        max_points: the grid step is ``ceil(sqrt(area / max_points))``.
        depth_range: valid depth, metres.
        gray: (h, w) uint8 grey levels of the crop, for the points' intensities.
        blur_sigma: Gaussian smoothing of ``gray``, pixels.

    Returns:
        ((M, 3) points, metres; (M,) smoothed grey levels or None; the grid step, pixels).
    """
    sel = mask & (depth >= depth_range[0]) & (depth <= depth_range[1])
    n = int(sel.sum())
    if n == 0:
        return np.zeros((0, 3)), None, 1
    step = max(1, int(np.ceil(np.sqrt(n / max_points))))
    vs, us = np.nonzero(sel[::step, ::step])
    vs, us = vs * step, us * step
    pts = backproject(us + origin[0], vs + origin[1], depth[vs, us], K)
    values = None
    if gray is not None:
        values = _smooth(gray, blur_sigma)[vs, us].astype(np.float64)
    return pts, values, step


def _smooth(gray: np.ndarray, sigma: float) -> np.ndarray:
    g = np.asarray(gray, dtype=np.float32)
    return cv2.GaussianBlur(g, (0, 0), sigma) if sigma > 0 else g


def _bilinear(img: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Bilinear samples of (h, w) ``img`` at float pixels (u, v), which must lie in [0, w-1) x [0, h-1)."""
    u0, v0 = np.floor(u).astype(np.int64), np.floor(v).astype(np.int64)
    a, b = u - u0, v - v0
    return (
        img[v0, u0] * (1 - a) * (1 - b)
        + img[v0, u0 + 1] * a * (1 - b)
        + img[v0 + 1, u0] * (1 - a) * b
        + img[v0 + 1, u0 + 1] * a * b
    )


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross product of (N, 3) arrays (cheaper than ``np.cross`` for small N)."""
    return np.stack(
        [
            a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1],
            a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
            a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0],
        ],
        axis=1,
    )


class _LiveSurface:
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
        u, v = u[ok], v[ok]
        z = self.z
        zc, zr, zl, zd, zu = z[v, u], z[v, u + b], z[v, u - b], z[v + b, u], z[v - b, u]
        x0, y0, K = self.x0, self.y0, self.K

        def lift(uu: np.ndarray, vv: np.ndarray, zz: np.ndarray) -> np.ndarray:
            return backproject(uu + x0, vv + y0, zz, K)

        P = lift(u, v, zc)
        dx = lift(u + b, v, zr) - lift(u - b, v, zl)
        dy = lift(u, v + b, zd) - lift(u, v - b, zu)
        n = _cross(dx, dy)
        norm = np.linalg.norm(n, axis=1)
        good = (
            (zr > 0)
            & (zl > 0)
            & (zd > 0)
            & (zu > 0)
            & (np.abs(dx[:, 2]) < self.max_jump * b * zc)
            & (np.abs(dy[:, 2]) < self.max_jump * b * zc)
            & (norm > 1e-12)
        )
        n = n / np.where(norm > 1e-12, norm, 1.0)[:, None]
        n = np.where((np.sum(n * P, axis=1) > 0)[:, None], -n, n)  # face the camera
        out = np.flatnonzero(ok)
        keep = np.zeros(len(ok), dtype=bool)
        keep[out[good]] = True
        return keep, P[good], n[good]


def _exp(w: np.ndarray) -> np.ndarray:
    theta = float(np.linalg.norm(w))
    if theta < 1e-12:
        return np.eye(3)
    k = w / theta
    Kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(theta) * Kx + (1.0 - np.cos(theta)) * Kx @ Kx


def icp_fit(
    model: np.ndarray,
    T0: np.ndarray,
    frame: RGBDFrame,
    mask: Mask,
    noise: DepthNoise | None = None,
    config: IcpConfig | None = None,
    model_gray: np.ndarray | None = None,
    step: int = 1,
) -> IcpFit | None:
    """Align object-frame surface points with the live RGB-D inside ``mask`` (module docstring).

    Args:
        model: (M, 3) object-frame surface points, metres.
        T0: (4, 4) initial ``camera_from_object``.
        frame: the live frame.
        mask: the object's live mask.
        noise: the depth sensor's noise model.
        config: parameters.
        model_gray: (M,) smoothed grey levels of the model points (:func:`surface_points`);
            None (or ``photometric_sigma`` None): depth only.
        step: the model's grid step, pixels (covariance inflation).

    Returns:
        The fit, or None when fewer than ``min_points`` model points ever find a correspondence.

    Raises:
        ValueError: ``model`` is not (M, 3) or ``T0`` not a finite (4, 4) matrix.
    """
    cfg = config or IcpConfig()
    noise = noise or DepthNoise()
    model = np.asarray(model, dtype=np.float64)
    T0 = np.asarray(T0, dtype=np.float64)
    if model.ndim != 2 or model.shape[1] != 3:
        raise ValueError(f"model has shape {model.shape}, expected (M, 3) object-frame points")
    if T0.shape != (4, 4) or not np.all(np.isfinite(T0)):
        raise ValueError(f"T0 has shape {T0.shape} or non-finite entries, expected a finite (4, 4) pose")
    if len(model) < cfg.min_points:
        return None
    live = _LiveSurface(frame, mask, 0.05, cfg.normal_px, round(cfg.grow_px * frame.width / 640))
    x0, y0 = live.x0, live.y0
    h, w = live.h, live.w
    K = frame.K
    R, t = T0[:3, :3].copy(), T0[:3, 3].copy()
    steps = 0
    photo = None
    if model_gray is not None and cfg.photometric_sigma is not None:
        model_gray = np.asarray(model_gray, dtype=np.float64)
        if model_gray.shape != (len(model),):
            raise ValueError(f"model_gray has shape {model_gray.shape}, expected ({len(model)},)")
        pad = 4 + round(cfg.grow_px * frame.width / 640)
        H, Wd = frame.depth.shape
        gx0, gy0 = max(0, mask.bbox[0] - pad), max(0, mask.bbox[1] - pad)
        gx1, gy1 = min(Wd, mask.bbox[2] + pad), min(H, mask.bbox[3] + pad)
        img = _smooth(frame.gray()[gy0:gy1, gx0:gx1], cfg.blur_sigma)
        gu = cv2.Sobel(img, cv2.CV_32F, 1, 0, ksize=3) / 8.0
        gv = cv2.Sobel(img, cv2.CV_32F, 0, 1, ksize=3) / 8.0
        photo = (img, gu, gv, gx0, gy0)

    def photometric(sel: np.ndarray, y: np.ndarray, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Photometric residuals (P,) and Jacobian rows (P, 6) of model points ``sel``, whitened."""
        assert photo is not None and model_gray is not None
        img, gu, gv, gx0, gy0 = photo
        z = X[:, 2]
        u = K[0, 0] * X[:, 0] / z + K[0, 1] * X[:, 1] / z + K[0, 2] - gx0
        v = K[1, 1] * X[:, 1] / z + K[1, 2] - gy0
        ok = (u >= 0) & (v >= 0) & (u < img.shape[1] - 1) & (v < img.shape[0] - 1)
        u, v, z, y, X, sel = u[ok], v[ok], z[ok], y[ok], X[ok], sel[ok]
        r = _bilinear(img, u, v) - model_gray[sel]
        r = r - median(r) if len(r) else r
        g = np.stack([_bilinear(gu, u, v), _bilinear(gv, u, v)], axis=1)
        # d(u, v)/dX for the pinhole, then dX/d(w, d) = [-[y]x, I]
        du = np.stack([K[0, 0] / z, np.zeros_like(z), -K[0, 0] * X[:, 0] / z**2], axis=1)
        dv = np.stack([np.zeros_like(z), K[1, 1] / z, -K[1, 1] * X[:, 1] / z**2], axis=1)
        gX = g[:, :1] * du + g[:, 1:] * dv
        J = np.concatenate([_cross(y, gX), gX], axis=1)
        s = float(cfg.photometric_sigma)  # type: ignore[arg-type]
        return r / s, J / s

    def associate(R: np.ndarray, t: np.ndarray):
        y = model @ R.T
        X = y + t
        z = X[:, 2]
        zs = np.where(z > 1e-6, z, 1e-6)
        u = np.rint(K[0, 0] * X[:, 0] / zs + K[0, 1] * X[:, 1] / zs + K[0, 2]).astype(np.int64) - x0
        v = np.rint(K[1, 1] * X[:, 1] / zs + K[1, 2]).astype(np.int64) - y0
        inside = (z > 1e-6) & (u >= 0) & (v >= 0) & (u < w) & (v < h)
        idx = np.flatnonzero(inside)
        good, q, n = live.lookup(u[idx], v[idx])
        idx = idx[good]
        return idx, y[idx], X[idx], q, n, (u, v, inside, z)

    wide = True  # the wide gate until the steps settle, then the tight one
    for k in range(cfg.iterations):
        idx, y, X, q, n, _ = associate(R, t)
        if len(idx) < cfg.min_points:
            return None
        sig = noise.sigma(q[:, 2]).astype(np.float64)
        gate = (cfg.gate if wide else 0.0) + 3.0 * sig + cfg.tolerance
        r = np.sum((X - q) * n, axis=1)
        near = np.linalg.norm(X - q, axis=1) < gate
        if int(near.sum()) < cfg.min_points:
            return None
        rs = r[near] / sig[near]
        J = np.concatenate([_cross(y[near], n[near]), n[near]], axis=1) / sig[near, None]
        if photo is not None:
            rp, Jp = photometric(idx[near], y[near], X[near])
            rs, J = np.concatenate([rs, rp]), np.concatenate([J, Jp])
        wgt = np.where(np.abs(rs) <= 1.345, 1.0, 1.345 / np.maximum(np.abs(rs), 1e-12))
        H = J.T @ (J * wgt[:, None])
        g = J.T @ (wgt * rs)
        try:
            delta = -np.linalg.solve(H + 1e-9 * np.trace(H) * np.eye(6), g)
        except np.linalg.LinAlgError:
            return None
        R = _exp(delta[:3]) @ R
        t = t + delta[3:]
        steps = k + 1
        small = np.linalg.norm(delta[:3]) < 5e-4 and np.linalg.norm(delta[3:]) < 5e-4
        if small and not wide:
            break
        wide = wide and not small and k < cfg.iterations // 2
    idx, y, X, q, n, (u, v, inside, z) = associate(R, t)
    if len(idx) < 6:
        return None
    sig = noise.sigma(q[:, 2]).astype(np.float64)
    tol = 3.0 * sig + cfg.tolerance
    r = np.sum((X - q) * n, axis=1)
    near = np.linalg.norm(X - q, axis=1) < tol
    m = int(near.sum())
    # free space: the sensor sees farther than the fit's surface (anywhere in the box, in or out of the mask)
    ib = np.flatnonzero(inside)
    zl = frame.depth[v[ib] + y0, u[ib] + x0].astype(np.float64)
    zp = z[ib]
    behind = (zl > 0) & (zl > zp + 3.0 * noise.sigma(zp).astype(np.float64) + cfg.gate)
    free = int(behind.sum())
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    if m < 6:
        return IcpFit(T, m, len(idx), m, free, np.inf, np.inf, np.inf, None, steps)
    rn = r[near]
    rmse = float(np.sqrt(np.mean(rn**2)))
    rmse_sigma = float(np.sqrt(np.mean((rn / sig[near]) ** 2)))
    rs = rn / sig[near]
    J = np.concatenate([_cross(y[near], n[near]), n[near]], axis=1) / sig[near, None]
    H_depth = J.T @ J
    n_photo = 0
    if photo is not None:
        rp, Jp = photometric(idx[near], y[near], X[near])
        rs, J, n_photo = np.concatenate([rs, rp]), np.concatenate([J, Jp]), len(rp)
    H = J.T @ J
    dof = max(len(rs) - 6, 1)
    inflation = max(1.0, (cfg.correlation_px / max(step, 1)) ** 2)
    s2 = max(float(np.sum(np.minimum(rs**2, 9.0))) / dof, 1.0) * inflation
    try:
        cov = s2 * np.linalg.inv(H)
        cov = 0.5 * (cov + cov.T)
        if not np.all(np.isfinite(cov)) or np.any(np.diag(cov) < 0):
            cov = None
    except np.linalg.LinAlgError:
        cov = None
    c = X[near] - X[near].mean(axis=0)
    L = float(np.sqrt(np.mean(np.sum(c**2, axis=1)))) or 1.0
    # the same step about the centroid m with rotations scaled by the radius L: w = w' / L and
    # d = d' + [m - t]x w, so that H' = A^T H A compares metres with metres
    mt = X[near].mean(axis=0) - t
    A = np.eye(6)
    A[:3, :3] /= L
    A[3:, :3] = np.array([[0.0, -mt[2], mt[1]], [mt[2], 0.0, -mt[0]], [-mt[1], mt[0], 0.0]]) / L
    Hc = A.T @ H_depth @ A  # depth terms only: shading on a smooth ball must not pin its turns
    ev = np.linalg.eigvalsh(0.5 * (Hc + Hc.T))
    condition = float(np.sqrt(ev[-1] / ev[0])) if ev[0] > 1e-12 * max(ev[-1], 1e-300) else float("inf")
    return IcpFit(T, m, len(idx), m, free, rmse, rmse_sigma, condition, cov, steps, n_photo)


def geometric_condition(
    frame: RGBDFrame, mask: Mask, config: IcpConfig | None = None, noise: DepthNoise | None = None
) -> float:
    """The condition number (module docstring) of the depth-only fit of a view to itself.

    A view whose surface does not pin all six degrees of freedom (a plane, a sphere, a
    cylinder's side) has a large one: depth alone can never measure its pose.

    Returns:
        The condition number; inf when the view has too few depth pixels to fit.
    """
    cfg = config or IcpConfig()
    x0, y0, x1, y1 = mask.bbox
    pts, _, step = surface_points(frame.depth[y0:y1, x0:x1], mask.crop, (x0, y0), frame.K, cfg.max_points)
    own = IcpConfig(
        max_points=cfg.max_points,
        iterations=1,
        min_points=cfg.min_points,
        photometric_sigma=None,
        normal_px=cfg.normal_px,
        grow_px=0,
    )
    fit = icp_fit(pts, np.eye(4), frame, mask, noise, own, step=step) if len(pts) else None
    return float("inf") if fit is None else fit.condition
