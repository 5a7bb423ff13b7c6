"""Behaviour monitoring BM (Eq. 4.14-4.17): object pose from features matched to EEMS snapshots.

Parameters: :class:`PoseConfig` (:mod:`pal.perception.pose_config`); snapshot choice and
matching: :mod:`pal.perception.pose_matching`.

**Canonical object frame** (:mod:`pal.perception.pose_canonical`). The first view of an object with enough depth-backed features
(``min_canonical_points``) or, with the dense fit on, enough depth pixels (twice its
``min_points``) on a surface that pins all six degrees of freedom (a box, not a ball:
:func:`pal.perception.icp.geometric_condition`), and enough area (the gallery's ``min_area``,
or half of it where ``small_canonical_points`` keypoints have depth) defines its frame: origin at the median 3-D point
of that view's mask, axes parallel to the camera axes at that moment. That view becomes the
canonical snapshot, anchored with ``object_from_camera = [I, -c0]``.

**Per frame.** Live features (inside the live mask) are matched with the ratio test against up
to ``max_snapshots`` anchored snapshots, those whose capture orientation is closest to the last
estimated one (newest first without one). Matches outside either mask are dropped. Matched
snapshot keypoints are lifted to 3-D with their snapshot's depth in [``min_depth``,
``max_depth``] and mapped into the canonical frame through that snapshot's anchor, so the
correspondences of all tried snapshots are fused into one set ``x_object <-> x_live``.
Equivalently, per snapshot::

    camera_from_object(t) = camera_live_from_camera_snap · inverse(anchor_snap)

so the pose does not jump when the best-matching snapshot changes. ``camera_from_object`` is
found by seeded RANSAC (:func:`pal.perception.pnp.pnp_ransac`) whose hypotheses are 3-point
Kabsch fits of the pairs whose live keypoint has depth, 4-point AP3P solutions, and the pose
the camera's motion predicts for a static object (with that prediction, the snapshots'
features are also matched where it puts them, :func:`pal.perception.features.guided_matches`,
which finds the matches a wide baseline hides from the ratio test); inliers are within
``pnp_reprojection_px``
(pixels at 640 columns), and the best hypothesis is refined by Levenberg-Marquardt on the
reprojection error. Reprojection weighs the precise pixels, not the depth, whose noise grows
with z² (:mod:`pal.perception.noise`); depth still supplies the hypotheses and a check.

**Trust.** Every fit goes through the checks of :mod:`pal.perception.pose_checks` (inliers
and their ratio, reprojection error, conditioning of its covariance, agreement with the live
depth, speed in the world frame, and consistency with the camera's motion for an object
presumed static). An accepted pose is ``estimated`` and carries its covariance (the canonical definition too:
none in rotation, the depth noise and spread of its origin's median in translation); a failed one is
``rejected`` with the failed checks in its diagnostics. A new snapshot is anchored with
``inverse(camera_from_object(t))`` only when its pose was estimated with at least
``anchor_min_inliers`` inliers (see :meth:`PoseEstimator.anchor_for`). Anchors chain, so
orientation error accumulates slowly as an object turns through views it never showed before.

**Dense fallback** (:meth:`PoseEstimator.dense_request`, :meth:`PoseEstimator.dense_pose`; Π
runs the fits of all objects of a frame at once, :mod:`pal.perception.icp_fit_batch`). When
the features give no accepted pose and the object is presumed static (so the camera's motion predicts its pose), :mod:`pal.perception.icp` aligns the
surface and texture of its best snapshot with the live depth and grey levels (point-to-plane
ICP plus photometric terms, started at the prediction). That pose has solver ``icp``; it is
``estimated`` only if enough of the surface agrees with the live depth (few points in free
space), the residual is at the sensor's noise, the depth terms are well conditioned (no
unobservable slide), its covariance is precise (``icp.max_rotation_std_deg``,
``icp.max_translation_std``), and it passes the speed and static checks
(:mod:`pal.perception.pose_dense`); otherwise it is ``rejected`` with the failed checks.

**Prediction.** Π first offers a static object's egomotion prediction to
:func:`pal.perception.pose_predicted.predicted_pose`; when the live data confirm it, it is the
pose and this estimator is not called.

**Failures** without a fit are ``lost`` with a reason, or, if ``propagate_s > 0`` and the last
two estimated poses are recent, ``propagated`` by constant velocity — flagged and never counted
as valid. Errors are raised, never swallowed.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from pal.perception.features import FeatureExtractor, Features
from pal.perception.frames import RGBDFrame
from pal.perception.icp import IcpFit, icp_fit
from pal.perception.masks import Mask
from pal.perception.memory import AdmissionDecision, ObjectRecord
from pal.perception.pnp import RgbdFit, pnp_ransac
from pal.perception.pose_canonical import define_canonical
from pal.perception.pose_checks import Evidence, Limits, check_fit, motion_between
from pal.perception.pose_config import PoseConfig
from pal.perception.pose_dense import DenseRequest, dense_checks, dense_diagnostics, dense_request
from pal.perception.pose_filter import filter_static
from pal.perception.pose_matching import FeaturePairs, choose_snapshots, fuse_pairs
from pal.perception.spatial import lift
from pal.perception.trajectory import Pose, PoseDiagnostics

__all__ = ["PoseConfig", "PoseEstimator", "lift", "position_std"]


def position_std(pose: Pose, K: np.ndarray, floor: float = 0.002) -> np.ndarray | None:
    """Per-axis 1-sigma uncertainty (3,) of an *estimated* pose's position, metres.

    From the pose's covariance (translation block) when it has one, floored at ``floor``;
    otherwise the canonical definition's floor. None for propagated, rejected or lost poses
    (never reported as positions).
    """
    if not pose.is_valid or pose.camera_from_object is None:
        return None
    if pose.covariance is not None:
        std = np.sqrt(np.clip(np.diag(pose.covariance)[3:], 0.0, None))
        return np.sqrt(floor**2 + std**2)
    d = pose.diagnostics
    n = max(d.inliers - 6, 1)
    rmse = d.rmse or 0.0
    if d.solver == "pnp":
        z = max(float(pose.camera_from_object[2, 3]), 1e-3)
        s = z * rmse / float(min(K[0, 0], K[1, 1])) / np.sqrt(n)
        return np.sqrt(floor**2 + np.array([s, s, 3.0 * s]) ** 2)
    return np.full(3, np.sqrt(floor**2 + rmse**2 / n))


class PoseEstimator:
    """Estimates an object's pose in its canonical frame (module docstring).

    Args:
        config: parameters.
        rng: generator for Kabsch-RANSAC samples.
    """

    def __init__(self, config: PoseConfig | None = None, rng: np.random.Generator | int = 0) -> None:
        self.config = config or PoseConfig()
        self.rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
        self.extractor = FeatureExtractor(self.config.features)

    def features(self, gray: np.ndarray, mask: Mask) -> Features:
        """Features of the object ``mask`` in the (H, W) uint8 image ``gray``."""
        return self.extractor(gray, mask)

    def anchor_for(
        self,
        pose: Pose,
        record: ObjectRecord | None = None,
        world_from_camera: np.ndarray | None = None,
        camera_known: bool = False,
    ) -> np.ndarray | None:
        """object_from_camera with which a snapshot taken at this pose may be anchored, or None.

        An estimated pose with at least ``anchor_min_inliers`` inliers anchors its view. Without
        one, the view of an object not known to move and estimated within ``dense_horizon_s``
        is anchored where the camera's motion puts it, when that
        motion was measured (``camera_known``): a moving camera soon sees such an object from
        where its old snapshots no longer match, and the new view keeps its pose measurable.
        """
        d = pose.diagnostics
        if (
            pose.is_valid
            and pose.camera_from_object is not None
            and d.solver in ("kabsch", "pnp", "icp", "egomotion")
            and d.inliers >= self.config.anchor_min_inliers
        ):
            return np.linalg.inv(pose.camera_from_object)
        if (
            record is not None
            and camera_known
            and not pose.is_valid
            and not record.moving
            and record.world_pose is not None
            and pose.timestamp - record.world_pose[0] <= self.config.dense_horizon_s
        ):
            W = np.eye(4) if world_from_camera is None else world_from_camera
            return np.linalg.inv(np.linalg.inv(W) @ record.world_pose[1])
        return None

    def estimate(
        self,
        record: ObjectRecord,
        frame: RGBDFrame,
        gray: np.ndarray,
        mask: Mask,
        feats: Features,
        world_from_camera: np.ndarray | None = None,
    ) -> tuple[Pose, AdmissionDecision | None]:
        """The pose of ``record``'s object in ``frame``: from features, else from depth (ICP).

        Args:
            record: the object's record (gallery, trajectory, world-frame state).
            frame: the current frame.
            gray: its (H, W) uint8 luminance.
            mask: the object's mask in this frame.
            feats: the object's features in this frame.
            world_from_camera: (4, 4) pose of the camera in the world (from the camera's
                motion); None: the camera is static (identity).

        Returns:
            (pose, decision): ``decision`` is the admission of the canonical snapshot when this
            call defined the canonical frame, else None (the caller then runs the normal
            admission with :meth:`anchor_for`).
        """
        pose, decision = self.estimate_features(record, frame, gray, mask, feats, world_from_camera)
        request = self.dense_request(record, frame, mask, world_from_camera, pose)
        if request is None:
            return pose, decision
        cfg = self.config
        fit = icp_fit(
            request.model, request.prior, frame, mask, cfg.noise, cfg.icp, request.values, request.step
        )
        depth_pose = self.dense_pose(request, fit)
        return (pose if depth_pose is None else depth_pose), decision

    def estimate_features(
        self,
        record: ObjectRecord,
        frame: RGBDFrame,
        gray: np.ndarray,
        mask: Mask,
        feats: Features,
        world_from_camera: np.ndarray | None = None,
    ) -> tuple[Pose, AdmissionDecision | None]:
        """The feature-based pose, the first phase of :meth:`estimate` (arguments and result as there)."""
        cfg = self.config
        t = frame.timestamp
        W = np.eye(4) if world_from_camera is None else np.asarray(world_from_camera, dtype=np.float64)
        if record.gallery.canonical is None:
            pose, decision = define_canonical(cfg, record, frame, gray, mask, feats)
            if pose.is_valid and pose.camera_from_object is not None:
                record.world_pose = (t, W @ pose.camera_from_object)
                record.world_origin = record.world_pose[1]
            return pose, decision
        prior = None if record.world_pose is None else np.linalg.inv(W) @ record.world_pose[1]
        snaps = choose_snapshots(record, cfg.max_snapshots, prior)
        if not snaps:
            return self._fallback(record, t, PoseDiagnostics(reason="no anchored snapshot")), None
        pairs = fuse_pairs(self.extractor, cfg, snaps, frame, feats, prior)
        if pairs.obj is None:
            diag = PoseDiagnostics(
                matches=pairs.matches,
                reason=f"{pairs.n2} matches inside the masks with snapshot depth < {cfg.min_pairs}",
                attempts=len(snaps),
            )
            return self._fallback(record, t, diag), None
        px = max(1.5, cfg.pnp_reprojection_px * frame.width / 640.0)
        sigma_z, tol_z = self._depth_noise(pairs.live3d[:, 2])
        fit = pnp_ransac(
            pairs.obj,
            pairs.img,
            frame.K,
            rng=self.rng,
            iterations=cfg.ransac_iterations,
            reprojection_error=px,
            confidence=cfg.pnp_confidence,
            min_inliers=cfg.checks.min_inliers,
            image_points_3d=pairs.live3d,
            hypotheses=() if prior is None else (prior,),
            depth_tolerance=tol_z,
            depth_sigma=sigma_z,
        )
        if fit is None:
            diag = PoseDiagnostics(
                matches=pairs.matches,
                pairs=pairs.n3,
                reason=f"no fit with {cfg.checks.min_inliers} inliers among {pairs.n2} pairs",
                attempts=len(snaps),
            )
            return self._fallback(record, t, diag), None
        return self._checked_pose(record, frame, pairs, fit, prior, W, px, len(snaps)), None

    def _checked_pose(
        self,
        record: ObjectRecord,
        frame: RGBDFrame,
        pairs: FeaturePairs,
        fit: RgbdFit,
        prior: np.ndarray | None,
        W: np.ndarray,
        px: float,
        attempts: int,
    ) -> Pose:
        """The pose of a feature fit after the checks of :mod:`pal.perception.pose_checks`.

        ``estimated`` (and accepted into the record's world-frame state) or ``rejected``.
        """
        cfg = self.config
        t = frame.timestamp
        sigma_z, tol_z = self._depth_noise(pairs.live3d[:, 2])
        fit, notes, failed, moved = check_fit(
            Evidence(frame, pairs.obj, pairs.img, pairs.live3d, sigma_z, tol_z, px),
            fit,
            record,
            prior,
            W,
            Limits(cfg.checks, cfg.noise, cfg.ransac_threshold, cfg.max_speed, cfg.max_angular_speed),
        )
        used = pairs.owner[fit.inliers]
        top = int(np.bincount(used - used.min()).argmax() + used.min()) if used.size else None
        T = fit.matrix()
        cov = fit.covariance
        ratio = fit.num_inliers / pairs.n2
        if not failed:
            T = self._filtered(record, prior, T, t, moved, notes, cov)
        reason = "; ".join(notes) if notes else "ok"
        if failed:
            reason = "rejected: " + "; ".join(failed) + (f" ({reason})" if notes else "")
        diag = PoseDiagnostics(
            pairs.matches,
            pairs.n3,
            fit.num_inliers,
            fit.rmse,
            "pnp",
            reason,
            top,
            attempts,
            ratio,
            tuple(failed),
        )
        if failed:
            return Pose(t, "rejected", T, diag)
        self._accept(record, T, W, t, moved)
        return Pose(t, "estimated", T, diag, cov)

    def _filtered(
        self,
        record: ObjectRecord,
        prior: np.ndarray | None,
        T: np.ndarray,
        t: float,
        moved: bool,
        notes: list[str],
        covariance: np.ndarray | None,
    ) -> np.ndarray:
        """``T`` blended with the egomotion prediction ``prior`` of a static object (:mod:`pal.perception.pose_filter`)."""
        cfg = self.config
        if (
            cfg.filter is None
            or prior is None
            or moved
            or record.moving
            or record.world_pose is None
            or t - record.world_pose[0] > cfg.checks.static_horizon_s
        ):
            return T
        out, filtered = filter_static(prior, T, cfg.filter, covariance)
        if filtered:
            notes.append("filtered with the egomotion prior")
        return out

    def _accept(self, record: ObjectRecord, T: np.ndarray, W: np.ndarray, t: float, moved: bool) -> None:
        """Update the record's world-frame state with an accepted ``camera_from_object`` T."""
        world = W @ T
        if record.world_pose is not None and t > record.world_pose[0]:
            record.speed = motion_between(record.world_pose[1], world)[0] / (t - record.world_pose[0])
        record.world_pose = (t, world)
        if record.world_origin is None:
            record.world_origin = world
        if moved or motion_between(record.world_origin, world)[0] > self.config.checks.moving_threshold:
            record.moving = True

    def dense_request(
        self,
        record: ObjectRecord,
        frame: RGBDFrame,
        mask: Mask,
        world_from_camera: np.ndarray | None,
        feature_pose: Pose,
    ) -> DenseRequest | None:
        """The dense fit the object needs after its feature pose, the second phase of :meth:`estimate`.

        None when the features gave an accepted pose, the dense fit is off, the object has no
        canonical frame or is not presumed static (:func:`pal.perception.pose_dense.dense_request`).
        """
        cfg = self.config
        if feature_pose.source == "estimated" or cfg.icp is None or record.gallery.canonical is None:
            return None
        W = np.eye(4) if world_from_camera is None else np.asarray(world_from_camera, dtype=np.float64)
        return dense_request(cfg, record, frame, mask, W, feature_pose)

    def dense_pose(self, request: DenseRequest, fit: IcpFit | None) -> Pose | None:
        """The pose of a dense fit of ``request`` after its checks, the last phase of :meth:`estimate`.

        ``estimated`` (and accepted into the record's world-frame state) if it passes
        :func:`pal.perception.pose_dense.dense_checks`, else ``rejected`` when the features gave
        no transform either; None when there is no fit or the feature pose is kept.
        """
        if fit is None:
            return None
        cfg, record, W, prior = self.config, request.record, request.W, request.prior
        t = request.timestamp
        failed = dense_checks(fit, record, prior, W, t, cfg)
        feature_pose = request.feature_pose
        diag = dense_diagnostics(fit, request, failed)
        if failed:
            if feature_pose.source == "rejected" or feature_pose.camera_from_object is not None:
                return None  # keep the feature pose (rejected or propagated) and its reason
            return Pose(t, "rejected", fit.T, diag)
        T = self._filtered(record, prior, fit.T, t, False, [], fit.covariance)
        self._accept(record, T, W, t, False)
        return Pose(t, "estimated", T, diag, fit.covariance)

    def _depth_noise(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per-pair depth sigma and inlier tolerance, metres, at observed depths ``z`` (NaN: none).

        The snapshot's depth is as noisy as the live one, so sigma is ``sqrt(2)`` times the
        sensor's; the tolerance is ``3 sigma + ransac_threshold``.
        """
        zz = np.where(np.isfinite(z), z, 1.0)
        sigma = np.sqrt(2.0) * self.config.noise.sigma(zz).astype(np.float64) + 1e-3
        return sigma, 3.0 * sigma + self.config.ransac_threshold

    def missing(self, record: ObjectRecord, t: float, diag: PoseDiagnostics) -> Pose:
        """The pose sample of an object with no usable observation at ``t``: ``propagated`` or ``lost``.

        It is ``propagated`` (flagged) if propagation is on and the last estimates are recent.
        """
        return self._fallback(record, t, diag)

    def _fallback(self, record: ObjectRecord, t: float, diag: PoseDiagnostics) -> Pose:
        cfg = self.config
        last2 = record.trajectory.last_valid(2)
        if cfg.propagate_s > 0 and len(last2) == 2 and t - last2[1].timestamp <= cfg.propagate_s:
            (ta, Ta), (tb, Tb) = ((p.timestamp, p.camera_from_object) for p in last2)
            if Ta is not None and Tb is not None and tb > ta:
                s = (t - tb) / (tb - ta)
                T = np.eye(4)
                T[:3, 3] = Tb[:3, 3] + s * (Tb[:3, 3] - Ta[:3, 3])
                rel = Rotation.from_matrix(Tb[:3, :3] @ Ta[:3, :3].T).as_rotvec()
                T[:3, :3] = Rotation.from_rotvec(s * rel).as_matrix() @ Tb[:3, :3]
                d = PoseDiagnostics(
                    diag.matches,
                    diag.pairs,
                    diag.inliers,
                    diag.rmse,
                    "constant_velocity",
                    f"{diag.reason}; propagated {t - tb:.3f} s from the last estimate",
                    diag.snapshot,
                    diag.attempts,
                )
                return Pose(t, "propagated", T, d)
        return Pose(t, "lost", None, diag)
