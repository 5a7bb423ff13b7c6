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

The correspondences and the photometric term are in :mod:`pal.perception.icp_terms`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pal.checks import check_float, check_int
from pal.perception.frames import RGBDFrame, backproject
from pal.perception.icp_terms import LiveSurface, Match, Photometric, associate, cross, smooth
from pal.perception.masks import Mask
from pal.perception.noise import DepthNoise

__all__ = ["IcpConfig", "IcpFit", "geometric_condition", "icp_fit", "icp_score", "surface_points"]


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
        early_condition: the fit stops at its start when the condition number of its depth
            terms there exceeds this many times ``max_condition`` (it would be refused for
            geometry; scored where it started); None: always step.
        max_rotation_std_deg: largest rotation standard deviation of an accepted fit, deg ...
        max_translation_std: ... and translation standard deviation, metres (stricter than the
            feature fits' conditioning check: a dense fit is accepted only when it is precise).
    """

    max_points: int = 160
    iterations: int = 10
    gate: float = 0.05
    tolerance: float = 0.005
    min_points: int = 40
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
    early_condition: float | None = 2.0

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
        if self.early_condition is not None:
            check_float("early_condition", self.early_condition, 1.0)


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
        photometric_sigma: their robust spread (1.4826 median absolute residual) in units of
            the grey-level noise ``photometric_sigma`` (0 without them).
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
    photometric_sigma: float = 0.0

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
        values = smooth(gray, blur_sigma)[vs, us].astype(np.float64)
    return pts, values, step


def _exp(w: np.ndarray) -> np.ndarray:
    theta = float(np.linalg.norm(w))
    if theta < 1e-12:
        return np.eye(3)
    k = w / theta
    Kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(theta) * Kx + (1.0 - np.cos(theta)) * Kx @ Kx


def _depth_jacobian(m: Match, near: np.ndarray, sig: np.ndarray) -> np.ndarray:
    """Point-to-plane Jacobian rows (P, 6) of the correspondences ``near``, whitened by ``sig``."""
    return np.concatenate([cross(m.y[near], m.n[near]), m.n[near]], axis=1) / sig[near, None]


def _gauss_newton(
    model: np.ndarray,
    R: np.ndarray,
    t: np.ndarray,
    live: LiveSurface,
    noise: DepthNoise,
    cfg: IcpConfig,
    photo: Photometric | None,
) -> tuple[np.ndarray, np.ndarray, int] | None:
    """Robust Gauss-Newton steps from (R, t), the gate shrinking once they settle (module docstring).

    Returns:
        (R, t, steps taken), or None when too few correspondences remain or a step is singular.
    """
    steps = 0
    wide = True  # the wide gate until the steps settle, then the tight one
    for k in range(cfg.iterations):
        m = associate(model, R, t, live)
        if len(m.idx) < cfg.min_points:
            return None
        sig = noise.sigma(m.q[:, 2]).astype(np.float64)
        gate = (cfg.gate if wide else 0.0) + 3.0 * sig + cfg.tolerance
        r = np.sum((m.X - m.q) * m.n, axis=1)
        near = np.linalg.norm(m.X - m.q, axis=1) < gate
        if int(near.sum()) < cfg.min_points:
            return None
        rs = r[near] / sig[near]
        J = _depth_jacobian(m, near, sig)
        if k == 0 and cfg.early_condition is not None:
            if _condition(J.T @ J, m.X[near], t) > cfg.early_condition * cfg.max_condition:
                return R, t, 0  # a slide this surface cannot pin: the fit would fail the geometry check
        if photo is not None:
            rp, Jp = photo(m.idx[near], m.y[near], m.X[near])
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
    return R, t, steps


def _free_space(frame: RGBDFrame, live: LiveSurface, m: Match, noise: DepthNoise, gate: float) -> int:
    """Model points in front of which the sensor sees farther than the fit's surface (anywhere in the box)."""
    ib = np.flatnonzero(m.inside)
    zl = frame.depth[m.v[ib] + live.y0, m.u[ib] + live.x0].astype(np.float64)
    zp = m.z[ib]
    behind = (zl > 0) & (zl > zp + 3.0 * noise.sigma(zp).astype(np.float64) + gate)
    return int(behind.sum())


def _covariance(rs: np.ndarray, J: np.ndarray, correlation_px: float, step: int) -> np.ndarray | None:
    """``s^2 (J^T J)^-1``, inflated for correlated samples (module docstring); None when singular."""
    H = J.T @ J
    dof = max(len(rs) - 6, 1)
    inflation = max(1.0, (correlation_px / max(step, 1)) ** 2)
    s2 = max(float(np.sum(np.minimum(rs**2, 9.0))) / dof, 1.0) * inflation
    try:
        cov = s2 * np.linalg.inv(H)
        cov = 0.5 * (cov + cov.T)
        if not np.all(np.isfinite(cov)) or np.any(np.diag(cov) < 0):
            cov = None
    except np.linalg.LinAlgError:
        cov = None
    return cov


def _condition(H_depth: np.ndarray, X: np.ndarray, t: np.ndarray) -> float:
    """The geometric condition number of the depth terms' normal equations (module docstring)."""
    c = X - X.mean(axis=0)
    L = float(np.sqrt(np.mean(np.sum(c**2, axis=1)))) or 1.0
    # the same step about the centroid m with rotations scaled by the radius L: w = w' / L and
    # d = d' + [m - t]x w, so that H' = A^T H A compares metres with metres
    mt = X.mean(axis=0) - t
    A = np.eye(6)
    A[:3, :3] /= L
    A[3:, :3] = np.array([[0.0, -mt[2], mt[1]], [mt[2], 0.0, -mt[0]], [-mt[1], mt[0], 0.0]]) / L
    Hc = A.T @ H_depth @ A  # depth terms only: shading on a smooth ball must not pin its turns
    ev = np.linalg.eigvalsh(0.5 * (Hc + Hc.T))
    return float(np.sqrt(ev[-1] / ev[0])) if ev[0] > 1e-12 * max(ev[-1], 1e-300) else float("inf")


def _final_fit(
    model: np.ndarray,
    pose: tuple[np.ndarray, np.ndarray, int],
    frame: RGBDFrame,
    live: LiveSurface,
    noise: DepthNoise,
    cfg: IcpConfig,
    photo: Photometric | None,
    step: int,
) -> IcpFit | None:
    """The fit at the converged pose ``(R, t, steps)``, scored within the final gate.

    Agreement, free space, residuals, covariance and condition (module docstring).
    """
    R, t, steps = pose
    m = associate(model, R, t, live)
    if len(m.idx) < 6:
        return None
    sig = noise.sigma(m.q[:, 2]).astype(np.float64)
    tol = 3.0 * sig + cfg.tolerance
    r = np.sum((m.X - m.q) * m.n, axis=1)
    near = np.linalg.norm(m.X - m.q, axis=1) < tol
    agree = int(near.sum())
    free = _free_space(frame, live, m, noise, cfg.gate)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    if agree < 6:
        return IcpFit(T, agree, len(m.idx), agree, free, np.inf, np.inf, np.inf, None, steps)
    rn = r[near]
    rmse = float(np.sqrt(np.mean(rn**2)))
    rmse_sigma = float(np.sqrt(np.mean((rn / sig[near]) ** 2)))
    rs = rn / sig[near]
    J = _depth_jacobian(m, near, sig)
    H_depth = J.T @ J
    n_photo, spread = 0, 0.0
    if photo is not None:
        rp, Jp = photo(m.idx[near], m.y[near], m.X[near])
        rs, J, n_photo = np.concatenate([rs, rp]), np.concatenate([J, Jp]), len(rp)
        spread = 1.4826 * float(np.median(np.abs(rp))) if len(rp) else 0.0
    cov = _covariance(rs, J, cfg.correlation_px, step)
    condition = _condition(H_depth, m.X[near], t)
    return IcpFit(T, agree, len(m.idx), agree, free, rmse, rmse_sigma, condition, cov, steps, n_photo, spread)


def _checked(model: np.ndarray, T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    model, T = np.asarray(model, dtype=np.float64), np.asarray(T, dtype=np.float64)
    if model.ndim != 2 or model.shape[1] != 3:
        raise ValueError(f"model has shape {model.shape}, expected (M, 3) object-frame points")
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise ValueError(f"T0 has shape {T.shape} or non-finite entries, expected a finite (4, 4) pose")
    return model, T


def _terms(
    frame: RGBDFrame, mask: Mask, cfg: IcpConfig, model: np.ndarray, model_gray: np.ndarray | None
) -> tuple[LiveSurface, Photometric | None]:
    grow = round(cfg.grow_px * frame.width / 640)
    live = LiveSurface(frame, mask, 0.05, cfg.normal_px, grow)
    if model_gray is None or cfg.photometric_sigma is None:
        return live, None
    model_gray = np.asarray(model_gray, dtype=np.float64)
    if model_gray.shape != (len(model),):
        raise ValueError(f"model_gray has shape {model_gray.shape}, expected ({len(model)},)")
    return live, Photometric(frame, mask, model_gray, grow, cfg.blur_sigma, cfg.photometric_sigma)


def icp_score(
    model: np.ndarray,
    T: np.ndarray,
    frame: RGBDFrame,
    mask: Mask,
    noise: DepthNoise | None = None,
    config: IcpConfig | None = None,
    model_gray: np.ndarray | None = None,
    step: int = 1,
) -> IcpFit | None:
    """The fit of :func:`icp_fit` scored at ``T`` itself, without a step (a prediction checked).

    Agreement, free space, residuals, covariance and condition of the correspondences at ``T``
    (arguments as :func:`icp_fit`); None when fewer than 6 model points find one.
    """
    cfg = config or IcpConfig()
    model, T = _checked(model, T)
    live, photo = _terms(frame, mask, cfg, model, model_gray)
    return _final_fit(model, (T[:3, :3], T[:3, 3], 0), frame, live, noise or DepthNoise(), cfg, photo, step)


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
    model, T0 = _checked(model, T0)
    if len(model) < cfg.min_points:
        return None
    live, photo = _terms(frame, mask, cfg, model, model_gray)
    pose = _gauss_newton(model, T0[:3, :3].copy(), T0[:3, 3].copy(), live, noise, cfg, photo)
    if pose is None:
        return None
    return _final_fit(model, pose, frame, live, noise, cfg, photo, step)


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
        early_condition=None,
    )
    fit = icp_fit(pts, np.eye(4), frame, mask, noise, own, step=step) if len(pts) else None
    return float("inf") if fit is None else fit.condition
