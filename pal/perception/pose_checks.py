"""Validity checks of an object pose fit: which poses can be trusted, and why the others are rejected.

A fit from :func:`pal.perception.pnp.pnp_ransac` becomes an ``estimated`` pose only if it
passes every check of :func:`failed_checks`; otherwise it is ``rejected`` with the names and
values of the failed checks:

- ``inliers``: at least ``min_inliers`` inliers, and ``inlier_ratio``: at least
  ``min_inlier_ratio`` of the pairs tried;
- ``reprojection``: inlier RMSE at most ``max_rmse_px`` (pixels at 640 columns);
- ``conditioning``: the Gauss-Newton covariance exists, with rotation and translation
  standard deviations at most ``max_rotation_std_deg`` and ``max_translation_std`` (few,
  clustered or nearly collinear inliers give poses that fit them and nothing else);
- ``spread``: the inliers' second principal standard deviation (in the object frame) is at
  least ``min_spread_sigmas`` times the depth noise ``sigma_z`` at the object's distance: a
  far, thin set of inliers (a line or a small patch 3-5 m away) pins the pixels it fits and not
  the rotation about it, and its depth cannot tell;
- ``depth``: where the live pixels have depth, at least ``min_depth_agreement`` of the inliers
  lie within ``3 sigma_z + depth_tolerance`` of where the pose puts them (a pose that fits the
  pixels with the wrong depth is a mirror or scale error);
- ``speed``: the object's motion since its last estimate, **in the world frame** (the camera's
  own motion removed), is at most ``max_speed`` and ``max_angular_speed`` plus 3 sigma: a camera
  moving fast past static objects does not trip it;
- ``static``: an object *presumed static* (it has not moved more than ``moving_threshold`` in
  the world since its first pose, and had an estimated pose within ``static_horizon_s``: what
  was out of sight may have been moved) must stay where the camera's motion predicts it, within
  ``static_translation`` and ``static_rotation_deg`` plus 3 sigma (at most the bounds again),
  unless the prediction is
  refuted by the data (it explains fewer than ``static_support`` of the fit's inliers); when
  the prediction is nearly as good, the estimator refines it instead, and a refinement that
  drifts out of those bounds fails the check (the data pin the pose too loosely to correct it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from pal.checks import check_float, check_int
from pal.perception.frames import RGBDFrame
from pal.perception.noise import DepthNoise
from pal.perception.pnp import RgbdFit, refine_pose, reprojection_errors

if TYPE_CHECKING:
    from pal.perception.memory import ObjectRecord

__all__ = [
    "Evidence",
    "Limits",
    "PoseChecks",
    "check_fit",
    "motion_between",
    "rotation_deg",
    "sigmas",
    "static_bounds",
]


@dataclass(frozen=True)
class PoseChecks:
    """Thresholds of the validity checks (module docstring).

    Attributes:
        min_inliers: fewest inliers of an estimated pose.
        min_inlier_ratio: fewest inliers per pair tried.
        max_rmse_px: largest inlier reprojection RMSE, pixels at 640 columns.
        max_rotation_std_deg: largest rotation standard deviation, deg.
        max_translation_std: largest translation standard deviation, metres.
        min_spread_sigmas: the inliers' second principal std must reach this many ``sigma_z``.
        min_depth_agreement: fraction of depth-backed inliers that must agree with the pose.
        depth_tolerance: depth disagreement allowed beyond 3 sigma of the sensor, metres.
        static_translation: how far an object presumed static may be from its predicted pose,
            metres (plus 3 sigma) ...
        static_rotation_deg: ... and how much it may turn, deg (plus 3 sigma).
        static_support: the prediction of a static object is refuted only if it explains fewer
            than this fraction of the fit's inliers.
        moving_threshold: an object is no longer presumed static once it has moved this far
            in the world from its first estimated pose, metres.
        static_horizon_s: ... or once it has had no estimated pose for this long, s.
    """

    min_inliers: int = 8
    min_inlier_ratio: float = 0.3
    max_rmse_px: float = 3.0
    max_rotation_std_deg: float = 3.0
    max_translation_std: float = 0.03
    min_spread_sigmas: float = 3.0
    min_depth_agreement: float = 0.5
    depth_tolerance: float = 0.01
    static_translation: float = 0.02
    static_rotation_deg: float = 3.0
    static_support: float = 0.7
    moving_threshold: float = 0.03
    static_horizon_s: float = 0.25

    def __post_init__(self) -> None:
        check_int("min_inliers", self.min_inliers, minimum=4)
        for name in ("min_inlier_ratio", "min_depth_agreement", "static_support"):
            check_float(name, getattr(self, name), 0.0, 1.0)
        for name in (
            "max_rmse_px",
            "max_rotation_std_deg",
            "max_translation_std",
            "min_spread_sigmas",
            "depth_tolerance",
            "static_translation",
            "static_rotation_deg",
            "moving_threshold",
            "static_horizon_s",
        ):
            check_float(name, getattr(self, name), 0.0, open_low=True)


def rotation_deg(Ra: np.ndarray, Rb: np.ndarray) -> float:
    """Angle of ``Ra^T Rb``, degrees."""
    c = (np.trace(np.asarray(Ra).T @ np.asarray(Rb)) - 1.0) / 2.0
    return math.degrees(math.acos(float(np.clip(c, -1.0, 1.0))))


def motion_between(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """Translation (metres, of the origin) and rotation (deg) between two (4, 4) poses."""
    return float(np.linalg.norm(b[:3, 3] - a[:3, 3])), rotation_deg(a[:3, :3], b[:3, :3])


def sigmas(covariance: np.ndarray | None) -> tuple[float, float]:
    """(rotation std deg, translation std m) of a (6, 6) pose covariance (inf without one)."""
    if covariance is None:
        return math.inf, math.inf
    d = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    return math.degrees(float(np.linalg.norm(d[:3]))), float(np.linalg.norm(d[3:]))


@dataclass(frozen=True, eq=False)
class Evidence:
    """What a fit is checked against.

    Attributes:
        frame: the live frame.
        obj: (N, 3) object-frame points of the pairs, metres.
        img: (N, 2) their live pixels.
        live3d: (N, 3) their live camera-frame points, NaN rows without depth, metres.
        sigma_z: (N,) depth noise of the pairs, metres.
        tol_z: (N,) depth tolerance of an inlier, metres.
        px: reprojection inlier threshold, pixels.
    """

    frame: RGBDFrame
    obj: np.ndarray
    img: np.ndarray
    live3d: np.ndarray
    sigma_z: np.ndarray
    tol_z: np.ndarray
    px: float


@dataclass(frozen=True)
class Limits:
    """The thresholds :func:`check_fit` applies (from :class:`pal.perception.pose_config.PoseConfig`).

    Attributes:
        checks: the validity checks' thresholds.
        noise: the depth sensor's noise model.
        tolerance: 3-D agreement tolerance, metres.
        max_speed: world-frame speed limit, m/s.
        max_angular_speed: world-frame turn-rate limit, rad/s.
    """

    checks: PoseChecks
    noise: DepthNoise
    tolerance: float
    max_speed: float
    max_angular_speed: float


def _near(prior: np.ndarray, fit: RgbdFit, chk: PoseChecks) -> bool:
    """Whether ``fit`` lies within the static bounds of the prediction ``prior`` (:func:`static_bounds`)."""
    dist, turn = motion_between(prior, fit.matrix())
    bound_m, bound_deg = static_bounds(chk, fit.covariance)
    return dist <= bound_m and turn <= bound_deg


def static_bounds(chk: PoseChecks, covariance: np.ndarray | None) -> tuple[float, float]:
    """How far (metres, degrees) a static object's fit may lie from its prediction.

    The static bounds plus 3 sigma of the fit, the 3 sigma capped at the bounds themselves: a
    loose fit, accepted against a prediction that is itself an accepted fit, is never more
    than twice the bounds off.
    """
    rot_std, t_std = sigmas(covariance)
    return (
        chk.static_translation + min(3 * t_std, chk.static_translation),
        chk.static_rotation_deg + min(3 * rot_std, chk.static_rotation_deg),
    )


def _static(
    ev: Evidence, fit: RgbdFit, prior: np.ndarray, chk: PoseChecks, notes: list[str]
) -> tuple[RgbdFit, str | None, bool]:
    """The ``static`` check: (the fit or the refined prediction, a failure or None, moved)."""
    if _near(prior, fit, chk):
        return fit, None, False
    dist, turn = motion_between(prior, fit.matrix())
    support = int((reprojection_errors(prior, ev.obj, ev.img, ev.frame.K) < ev.px).sum())
    if support < chk.static_support * fit.num_inliers:
        notes.append(f"moved: the static prediction explains {support} of {fit.num_inliers} inliers")
        return fit, None, True
    refined = refine_pose(
        ev.obj,
        ev.img,
        ev.frame.K,
        prior,
        ev.px,
        chk.min_inliers,
        live_z=ev.live3d[:, 2],
        depth_sigma=ev.sigma_z,
        depth_tolerance=ev.tol_z,
    )
    if refined is not None and refined.num_inliers >= support and _near(prior, refined, chk):
        notes.append(
            f"the static prediction explains {support} of the fit's {fit.num_inliers} inliers: refined it"
        )
        return refined, None, False
    return (
        fit,
        f"static: {dist:.3f} m and {turn:.1f} deg from where the camera's motion puts a static object",
        False,
    )


def _spread(inliers: np.ndarray, fit: RgbdFit, noise: DepthNoise, k: float) -> str | None:
    """The ``spread`` check on (N, 3) object-frame inliers: a failure message or None."""
    if len(inliers) < 3:
        return None
    z = float(np.median(inliers @ fit.R[2] + fit.t[2]))
    sd = np.linalg.svd(inliers - inliers.mean(axis=0), compute_uv=False) / math.sqrt(len(inliers))
    need = k * float(noise.sigma(z))
    if sd[1] >= need:
        return None
    return (
        f"spread: inliers {100 * sd[1]:.1f} cm wide at {z:.2f} m < {k:g} x depth noise ({100 * need:.1f} cm)"
    )


def check_fit(
    ev: Evidence,
    fit: RgbdFit,
    record: ObjectRecord,
    prior: np.ndarray | None,
    world_from_camera: np.ndarray,
    limits: Limits,
) -> tuple[RgbdFit, list[str], list[str], bool]:
    """Run the validity checks of the module docstring on a fit.

    Args:
        ev: the pairs and the frame the fit was made from.
        fit: the fit (``camera_from_object``).
        record: the object's record (its last world pose, whether it is moving).
        prior: the pose the camera's motion predicts for a static object, or None.
        world_from_camera: (4, 4) the live camera's pose in the world.
        limits: the thresholds.

    Returns:
        (the fit, possibly replaced by the refined static prediction; notes; failed checks with
        their values; whether the data refuted the static prediction).
    """
    chk, frame = limits.checks, ev.frame
    notes: list[str] = []
    moved = False
    recent = record.world_pose is not None and frame.timestamp - record.world_pose[0] <= chk.static_horizon_s
    if prior is not None and not record.moving and recent:
        fit, failure, moved = _static(ev, fit, prior, chk, notes)
        if failure is not None:
            return fit, notes, [failure], False
    failed = []
    ratio = fit.num_inliers / max(len(ev.obj), 1)
    if fit.num_inliers < chk.min_inliers:
        failed.append(f"inliers: {fit.num_inliers} < {chk.min_inliers}")
    if ratio < chk.min_inlier_ratio:
        failed.append(f"inlier_ratio: {ratio:.2f} < {chk.min_inlier_ratio:g}")
    max_rmse = chk.max_rmse_px * frame.width / 640.0
    if fit.rmse > max(max_rmse, 0.75):
        failed.append(f"reprojection: {fit.rmse:.2f} px > {max_rmse:.2f}")
    rot_std, t_std = sigmas(fit.covariance)
    if rot_std > chk.max_rotation_std_deg or t_std > chk.max_translation_std:
        failed.append(f"conditioning: std {rot_std:.1f} deg, {t_std:.3f} m")
    spread = _spread(ev.obj[fit.inliers], fit, limits.noise, chk.min_spread_sigmas)
    if spread is not None:
        failed.append(spread)
    deep = np.all(np.isfinite(ev.live3d), axis=1)
    near = (fit.inliers | (reprojection_errors(fit.matrix(), ev.obj, ev.img, frame.K) < ev.px)) & deep
    if near.sum() >= 3:
        pred = ev.obj[near] @ fit.R.T + fit.t
        tol = 3.0 * limits.noise.sigma(pred[:, 2]) + chk.depth_tolerance
        agree = float(np.mean(np.abs(pred[:, 2] - ev.live3d[near, 2]) <= tol))
        if agree < chk.min_depth_agreement:
            failed.append(f"depth: {agree:.0%} of the reprojection inliers agree with the live depth")
    if record.world_pose is not None:
        t_last, last = record.world_pose
        dt = max(frame.timestamp - t_last, 1e-6)
        dist, turn = motion_between(last, world_from_camera @ fit.matrix())
        if dist > limits.max_speed * dt + 3 * t_std + 2 * limits.tolerance:
            failed.append(f"speed: {dist:.3f} m in {dt:.3f} s in the world frame")
        if math.radians(turn) > limits.max_angular_speed * dt + math.radians(5.0 + 3 * rot_std):
            failed.append(f"speed: {turn:.1f} deg in {dt:.3f} s in the world frame")
    return fit, notes, failed, moved
