"""The dense pose fallback's inputs and trust checks (:mod:`pal.perception.icp` inside Π's pose stage).

When an object's features give no accepted pose, :class:`pal.perception.pose.PoseEstimator`
aligns the surface of its best snapshot with the live frame. :func:`snapshot_surface` samples
that surface in the canonical object frame; :func:`dense_checks` decides whether the fit is
trusted. A dense fit is ``estimated`` only if it passes all of:

- ``points``: at least ``icp.min_points`` correspondences;
- ``agreement``: at least ``icp.min_agreement`` of the model points on valid live depth agree
  with it, free-space violations counting against it;
- ``residual``: RMS point-to-plane residual at most ``icp.max_rmse_sigma`` sigma_z;
- ``geometry``: condition number at most ``icp.max_condition`` (no unobservable slide);
- ``conditioning``: rotation and translation standard deviations at most
  ``icp.max_rotation_std_deg`` and ``icp.max_translation_std``;
- ``speed``: the motion since the last estimate **in the world frame** within the speed limits;
- ``static``: an object presumed static stays where the camera's motion puts it (within
  ``checks.static_translation`` and ``checks.static_rotation_deg`` plus 3 sigma, at most twice
  those: :func:`pal.perception.pose_checks.static_bounds`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import cv2
import numpy as np

from pal.perception.icp import IcpConfig, IcpFit, surface_points
from pal.perception.pose_checks import motion_between, sigmas, static_bounds
from pal.perception.pose_matching import choose_snapshots
from pal.perception.trajectory import PoseDiagnostics

if TYPE_CHECKING:
    from pal.perception.frames import RGBDFrame
    from pal.perception.masks import Mask
    from pal.perception.memory import ObjectRecord, Snapshot
    from pal.perception.pose_config import PoseConfig
    from pal.perception.trajectory import Pose

__all__ = ["DenseRequest", "dense_checks", "dense_diagnostics", "dense_request", "snapshot_surface"]


@dataclass(frozen=True, eq=False)
class DenseRequest:
    """One object's dense fit to run (:func:`dense_request`).

    Attributes:
        record: the object's record.
        mask: its live mask.
        W: (4, 4) the live camera's pose in the world.
        prior: (4, 4) the predicted ``camera_from_object`` the fit starts from.
        snapshot: the snapshot whose surface is fitted.
        model: (M, 3) its surface in the object frame, metres; ``values`` (M,) its grey levels;
            ``step`` its grid step, pixels (:func:`snapshot_surface`).
        feature_pose: the pose the features gave.
        timestamp: the frame's time, s.
    """

    record: ObjectRecord
    mask: Mask
    W: np.ndarray
    prior: np.ndarray
    snapshot: Snapshot
    model: np.ndarray
    values: np.ndarray
    step: int
    feature_pose: Pose
    timestamp: float


def dense_request(
    config: PoseConfig, record: ObjectRecord, frame: RGBDFrame, mask: Mask, W: np.ndarray, feature_pose: Pose
) -> DenseRequest | None:
    """The dense fit of an object presumed static, or None (``config.icp`` must be set).

    Only an object presumed static is fitted (not moving, estimated within
    ``dense_horizon_s``): the fit starts from where the camera's motion puts it (its last
    world pose seen from the live camera) and uses the surface of the snapshot closest to that
    in orientation. A moving object's masks can hold pieces of the table or a hand that pin a
    pose its own surface cannot (a rolling one-colour ball), so it is left to its features.
    None also when no snapshot is anchored.
    """
    cfg = config
    assert cfg.icp is not None
    if (
        record.world_pose is None
        or record.moving
        or frame.timestamp - record.world_pose[0] > cfg.dense_horizon_s
    ):
        return None
    prior = np.linalg.inv(W) @ record.world_pose[1]
    snaps = choose_snapshots(record, cfg.max_snapshots, prior)
    if not snaps or snaps[0].anchor is None:
        return None
    model, values, step = snapshot_surface(snaps[0], cfg.icp, (cfg.min_depth, cfg.max_depth))
    return DenseRequest(record, mask, W, prior, snaps[0], model, values, step, feature_pose, frame.timestamp)


def dense_diagnostics(fit: IcpFit, request: DenseRequest, failed: list[str]) -> PoseDiagnostics:
    """The diagnostics of a dense fit with its failed checks (``solver`` ``icp``)."""
    before = request.feature_pose.diagnostics.reason
    return PoseDiagnostics(
        request.feature_pose.diagnostics.matches,
        fit.visible,
        fit.points,
        fit.rmse,
        "icp",
        (
            f"rejected: {'; '.join(failed)} (depth fit; features: {before})"
            if failed
            else f"depth fit; features: {before}"
        ),
        request.snapshot.index,
        1,
        fit.agreement,
        tuple(failed),
    )


def snapshot_surface(
    snap: Snapshot, config: IcpConfig, depth_range: tuple[float, float]
) -> tuple[np.ndarray, np.ndarray, int]:
    """A snapshot's surface in the canonical object frame: (points (M, 3) m, grey levels (M,), grid step px).

    Computed once per snapshot and setting (kept in ``snap.surfaces``; the arrays are read-only).

    Raises:
        ValueError: the snapshot is not anchored.
    """
    if snap.anchor is None:
        raise ValueError(f"snapshot {snap.index} has no anchor: its surface has no object-frame coordinates")
    key = (config.max_points, config.blur_sigma, tuple(depth_range), snap.anchor.tobytes())
    if key not in snap.surfaces:
        snap.surfaces[key] = _surface(snap, config, depth_range)
    return snap.surfaces[key]


def _surface(
    snap: Snapshot, config: IcpConfig, depth_range: tuple[float, float]
) -> tuple[np.ndarray, np.ndarray, int]:
    assert snap.anchor is not None
    gray = cv2.cvtColor(np.ascontiguousarray(snap.rgb), cv2.COLOR_RGB2GRAY)
    pts, values, step = surface_points(
        snap.depth,
        snap.mask,
        (snap.bbox[0], snap.bbox[1]),
        snap.K,
        config.max_points,
        depth_range,
        gray,
        config.blur_sigma,
    )
    assert values is not None
    model = pts @ snap.anchor[:3, :3].T + snap.anchor[:3, 3]
    model.flags.writeable = values.flags.writeable = False
    return model, values, step


def dense_checks(
    fit: IcpFit, record: ObjectRecord, prior: np.ndarray, W: np.ndarray, t: float, config: PoseConfig
) -> list[str]:
    """The failed checks of a dense fit (module docstring), each with its value.

    Args:
        fit: the fit.
        record: the object's record (its last world pose, whether it is moving).
        prior: (4, 4) the predicted ``camera_from_object`` the fit started from.
        W: (4, 4) the live camera's pose in the world.
        t: the frame's time, s.
        config: the pose estimator's parameters (``config.icp`` must be set).

    Returns:
        The failed checks; empty when the fit is accepted.
    """
    cfg, icp, chk = config, config.icp, config.checks
    assert icp is not None
    failed = []
    if fit.points < icp.min_points:
        failed.append(f"points: {fit.points} < {icp.min_points}")
    if fit.agreement < icp.min_agreement:
        failed.append(
            f"agreement: {fit.agreement:.0%} of the visible surface agrees ({fit.free_space} points in free space)"
        )
    if fit.rmse_sigma > icp.max_rmse_sigma:
        failed.append(f"residual: {fit.rmse_sigma:.1f} sigma_z > {icp.max_rmse_sigma:g}")
    if fit.condition > icp.max_condition:
        failed.append(
            f"geometry: condition {fit.condition:.0f} > {icp.max_condition:g} (a slide is unobservable)"
        )
    rot_std, t_std = sigmas(fit.covariance)
    if rot_std > icp.max_rotation_std_deg or t_std > icp.max_translation_std:
        failed.append(f"conditioning: std {rot_std:.1f} deg, {t_std:.3f} m")
    if record.world_pose is not None:
        t_last, last = record.world_pose
        dt = max(t - t_last, 1e-6)
        dist, turn = motion_between(last, W @ fit.T)
        if dist > cfg.max_speed * dt + 3 * t_std + 2 * cfg.ransac_threshold:
            failed.append(f"speed: {dist:.3f} m in {dt:.3f} s in the world frame")
        if math.radians(turn) > cfg.max_angular_speed * dt + math.radians(5.0 + 3 * rot_std):
            failed.append(f"speed: {turn:.1f} deg in {dt:.3f} s in the world frame")
    recent = record.world_pose is not None and t - record.world_pose[0] <= cfg.dense_horizon_s
    if not record.moving and recent:
        dist, turn = motion_between(prior, fit.T)
        bound_m, bound_deg = static_bounds(chk, fit.covariance)
        if dist > bound_m or turn > bound_deg:
            failed.append(
                f"static: {dist:.3f} m and {turn:.1f} deg from where the camera's motion puts a static object"
            )
    return failed
