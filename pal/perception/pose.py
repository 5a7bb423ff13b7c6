"""Behaviour monitoring BM (Eq. 4.14-4.17): object pose from features matched to EEMS snapshots.

**Canonical object frame.** The first view of an object with enough depth-backed features
(``min_canonical_points``), area and sharpness defines its frame: origin at the median 3-D point
of that view's mask, axes parallel to the camera axes at that moment. That view becomes the
canonical snapshot, anchored with ``object_from_camera = [I, -c0]``.

**Per frame.** Live features (inside the live mask) are matched with the ratio test against up
to ``max_snapshots`` anchored snapshots, those whose capture orientation is closest to the last
estimated one (newest first without one). Matches outside either mask are dropped. Matched
snapshot keypoints are lifted to 3-D with their snapshot's depth in [``min_depth``,
``max_depth``] and mapped into the canonical frame through that snapshot's anchor, so the
correspondences of all tried snapshots are fused into one set ``x_object <-> x_live``. With at
least ``min_pairs`` pairs whose live keypoint also has depth, Kabsch inside RANSAC (threshold
``ransac_threshold`` metres) gives ``camera_from_object`` directly; otherwise — or if that fit
has too few inliers — PnP-RANSAC on the object-frame points and the live pixels (100
iterations, 6 px, 0.99). Equivalently, per snapshot::

    camera_from_object(t) = camera_live_from_camera_snap · inverse(anchor_snap)

so the pose does not jump when the best-matching snapshot changes. A new snapshot is anchored with
``inverse(camera_from_object(t))`` only when its pose came from Kabsch with at least
``anchor_min_inliers`` inliers (see :meth:`PoseEstimator.anchor_for`). Anchors chain, so
orientation error accumulates slowly as an object turns through views it never showed before
(measured on the analytic box at 640x480 with ORB: median 1.6° over a 90° turn, 3.6° over 180°;
SIFT roughly halves it at ~5x the feature cost).

**Failures** are ``lost`` with a reason, or, if ``propagate_s > 0`` and the last two estimated
poses are recent, ``propagated`` by constant velocity — flagged and never counted as valid. A
fit implying a translation faster than ``max_speed`` or a turn faster than ``max_angular_speed``
is rejected. Errors are raised, never swallowed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from pal.perception.features import FeatureConfig, FeatureExtractor, Features
from pal.perception.frames import RGBDFrame, backproject
from pal.perception.masks import Mask
from pal.perception.memory import AdmissionDecision, ObjectRecord, Snapshot
from pal.perception.rigid import pnp_ransac, ransac_rigid, to_homogeneous
from pal.perception.spatial import mask_points
from pal.perception.trajectory import Pose, PoseDiagnostics

__all__ = ["PoseConfig", "PoseEstimator", "lift", "position_std"]


@dataclass(frozen=True)
class PoseConfig:
    """Pose-estimation parameters.

    Attributes:
        features: feature detector/matcher settings (ORB default).
        min_depth, max_depth: depth accepted for lifting keypoints, metres.
        ransac_threshold: Kabsch-RANSAC inlier distance, metres (1-2 cm).
        ransac_iterations: Kabsch-RANSAC hypotheses.
        min_pairs: 3-D/3-D pairs needed to try Kabsch (and 2-D/3-D pairs for PnP).
        min_inliers: inliers needed to accept a fit.
        min_inlier_ratio: inliers / pairs needed to accept a fit.
        min_pnp_inliers: inliers needed to accept a PnP fit (2-D residuals over a small
            object discriminate less than 3-D ones, so more are required).
        pnp_iterations, pnp_reprojection_px, pnp_confidence: PnP-RANSAC fallback settings.
        max_snapshots: snapshots tried per frame.
        good_inliers: stop trying snapshots once a fit has this many inliers.
        anchor_min_inliers: Kabsch inliers needed to anchor a new snapshot with the pose.
        min_canonical_points: depth-backed keypoints needed to define the canonical frame.
        max_speed: fits implying a faster translation since the last estimate are rejected, m/s.
        max_angular_speed: ... or a faster rotation, rad/s.
        propagate_s: constant-velocity propagation horizon after the last estimate, s (0: off).
    """

    features: FeatureConfig = field(default_factory=FeatureConfig)
    min_depth: float = 0.1
    max_depth: float = 5.0
    ransac_threshold: float = 0.015
    ransac_iterations: int = 128
    min_pairs: int = 6
    min_inliers: int = 8
    min_inlier_ratio: float = 0.3
    min_pnp_inliers: int = 10
    pnp_iterations: int = 100
    pnp_reprojection_px: float = 6.0
    pnp_confidence: float = 0.99
    max_snapshots: int = 3
    good_inliers: int = 30
    anchor_min_inliers: int = 12
    min_canonical_points: int = 12
    max_speed: float = 2.0
    max_angular_speed: float = 2.0 * math.pi
    propagate_s: float = 0.5

    def __post_init__(self) -> None:
        if not 0 < self.min_depth < self.max_depth:
            raise ValueError(f"depth range [{self.min_depth}, {self.max_depth}] m is invalid")
        if not 0 < self.ransac_threshold <= 0.1:
            raise ValueError(
                f"ransac_threshold is {self.ransac_threshold} m; expected metres in (0, 0.1], e.g. 0.015"
            )
        if self.min_pairs < 6 or self.min_inliers < 3 or self.min_pnp_inliers < 4:
            raise ValueError(
                f"min_pairs >= 6, min_inliers >= 3 and min_pnp_inliers >= 4 are required; got {self}"
            )
        if (
            self.max_snapshots < 1
            or self.max_speed <= 0
            or self.max_angular_speed <= 0
            or self.propagate_s < 0
        ):
            raise ValueError(
                f"max_snapshots >= 1, max_speed > 0 and propagate_s >= 0 are required; got {self}"
            )


def lift(
    points: np.ndarray,
    depth: np.ndarray,
    origin: tuple[int, int],
    K: np.ndarray,
    min_depth: float,
    max_depth: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Lift pixels to 3-D with the depth at their nearest pixel.

    Args:
        points: (N, 2) full-frame pixel coordinates.
        depth: (h, w) float32 metres, the frame's depth or a crop of it.
        origin: (x0, y0) of ``depth`` in the full frame.
        K: (3, 3) full-frame intrinsics.
        min_depth: smallest depth accepted, metres.
        max_depth: largest depth accepted, metres.

    Returns:
        ((N, 3) camera-frame points, zero where invalid; (N,) bool valid).
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    u = np.rint(pts[:, 0]).astype(np.int64) - origin[0]
    v = np.rint(pts[:, 1]).astype(np.int64) - origin[1]
    inside = (u >= 0) & (v >= 0) & (u < depth.shape[1]) & (v < depth.shape[0])
    z = np.zeros(len(pts))
    z[inside] = depth[v[inside], u[inside]]
    valid = inside & (z >= min_depth) & (z <= max_depth)
    out = np.zeros((len(pts), 3))
    if valid.any():
        out[valid] = backproject(pts[valid, 0], pts[valid, 1], z[valid], K)
    return out, valid


def _angle(Ra: np.ndarray, Rb: np.ndarray) -> float:
    c = (np.trace(Ra.T @ Rb) - 1.0) / 2.0
    return float(np.arccos(np.clip(c, -1.0, 1.0)))


def position_std(pose: Pose, K: np.ndarray, floor: float = 0.002) -> np.ndarray | None:
    """Per-axis 1-sigma uncertainty (3,) of an *estimated* pose's position, metres.

    Kabsch: ``sqrt(floor² + rmse² / max(inliers - 6, 1))`` on every axis. PnP: the pixel RMSE
    converted to metres at the object's depth (``z · rmse / f``) on x and y, three times that
    on z (depth is poorly constrained by PnP), same inlier scaling. The canonical definition
    has only the floor. None for propagated or lost poses (never reported as positions).
    """
    if not pose.is_valid or pose.camera_from_object is None:
        return None
    d = pose.diagnostics
    n = max(d.inliers - 6, 1)
    if d.solver == "pnp" and d.rmse is not None:
        z = max(float(pose.camera_from_object[2, 3]), 1e-3)
        s = z * d.rmse / float(min(K[0, 0], K[1, 1])) / np.sqrt(n)
        return np.sqrt(floor**2 + np.array([s, s, 3.0 * s]) ** 2)
    rmse = d.rmse or 0.0
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

    def anchor_for(self, pose: Pose) -> np.ndarray | None:
        """object_from_camera with which a snapshot taken at this pose may be anchored, or None."""
        d = pose.diagnostics
        if (
            pose.is_valid
            and pose.camera_from_object is not None
            and d.solver == "kabsch"
            and d.inliers >= self.config.anchor_min_inliers
        ):
            return np.linalg.inv(pose.camera_from_object)
        return None

    def estimate(
        self, record: ObjectRecord, frame: RGBDFrame, gray: np.ndarray, mask: Mask, feats: Features
    ) -> tuple[Pose, AdmissionDecision | None]:
        """The pose of ``record``'s object in ``frame``.

        Returns:
            (pose, decision): ``decision`` is the admission of the canonical snapshot when this
            call defined the canonical frame, else None (the caller then runs the normal
            admission with :meth:`anchor_for`).
        """
        cfg = self.config
        t = frame.timestamp
        if record.gallery.canonical is None:
            return self._define_canonical(record, frame, gray, mask, feats)
        snaps = self._choose(record)
        if not snaps:
            return self._fallback(record, t, PoseDiagnostics(reason="no anchored snapshot")), None
        live_pts, live_valid = lift(
            feats.keypoints, frame.depth, (0, 0), frame.K, cfg.min_depth, cfg.max_depth
        )
        obj, live_idx, owner, has3d = [], [], [], []
        for snap in snaps:
            pairs, ref_pts, ref_valid = self._correspond(snap, feats)
            if len(pairs) == 0:
                continue
            anchor = snap.anchor
            if anchor is None:  # _choose only yields anchored snapshots
                continue
            obj.append(ref_pts @ anchor[:3, :3].T + anchor[:3, 3])
            live_idx.append(pairs[:, 0])
            owner.append(np.full(len(pairs), snap.index))
            has3d.append(ref_valid)
        matches = int(sum(len(i) for i in live_idx))
        if matches < cfg.min_pairs:
            diag = PoseDiagnostics(
                matches=matches,
                reason=f"{matches} matches inside the masks < {cfg.min_pairs}",
                attempts=len(snaps),
            )
            return self._fallback(record, t, diag), None
        obj_pts, li, own, ref_ok = (
            np.concatenate(obj),
            np.concatenate(live_idx),
            np.concatenate(owner),
            np.concatenate(has3d),
        )
        both = ref_ok & live_valid[li]
        n3 = int(both.sum())
        fit, solver, used, reason = None, "", np.zeros(0, dtype=np.int64), ""
        if n3 >= cfg.min_pairs:
            fit = ransac_rigid(
                obj_pts[both],
                live_pts[li[both]],
                cfg.ransac_threshold,
                self.rng,
                iterations=cfg.ransac_iterations,
                min_inliers=cfg.min_inliers,
            )
            if fit is not None and fit.num_inliers >= cfg.min_inlier_ratio * n3:
                solver, used = "kabsch", own[both][fit.inliers]
            else:
                reason = f"kabsch: {0 if fit is None else fit.num_inliers} inliers of {n3} pairs"
                fit = None
        else:
            reason = f"{n3} depth-backed pairs < {cfg.min_pairs}"
        if fit is None:
            n2 = int(ref_ok.sum())
            if n2 >= cfg.min_pairs:
                fit = pnp_ransac(
                    obj_pts[ref_ok],
                    feats.keypoints[li[ref_ok]],
                    frame.K,
                    iterations=cfg.pnp_iterations,
                    reprojection_error=cfg.pnp_reprojection_px,
                    confidence=cfg.pnp_confidence,
                    min_inliers=cfg.min_pnp_inliers,
                )
                if fit is not None and fit.num_inliers >= cfg.min_inlier_ratio * n2:
                    solver, used = "pnp", own[ref_ok][fit.inliers]
                else:
                    reason += f"; pnp: {0 if fit is None else fit.num_inliers} inliers of {n2}"
                    fit = None
            else:
                reason += f"; pnp: {n2} reference points with depth < {cfg.min_pairs}"
        if fit is None:
            diag = PoseDiagnostics(matches=matches, pairs=n3, reason=reason, attempts=len(snaps))
            return self._fallback(record, t, diag), None
        top = int(np.bincount(used - used.min()).argmax() + used.min())
        T = fit.matrix()
        diag = PoseDiagnostics(matches, n3, fit.num_inliers, fit.rmse, solver, "ok", top, len(snaps))
        implausible = self._implausible(record, t, T)
        if implausible:
            diag = PoseDiagnostics(
                matches, n3, fit.num_inliers, fit.rmse, solver, f"rejected: {implausible}", top, len(snaps)
            )
            return self._fallback(record, t, diag), None
        return Pose(t, "estimated", T, diag), None

    def _implausible(self, record: ObjectRecord, t: float, T: np.ndarray) -> str:
        """Why the motion from the last estimated pose to ``T`` is implausible ('' if it is not)."""
        cfg = self.config
        last = record.trajectory.last_valid(1)
        if not last or last[0].camera_from_object is None:
            return ""
        prev = last[0].camera_from_object
        dt = max(t - last[0].timestamp, 1e-6)
        jump = float(np.linalg.norm(T[:3, 3] - prev[:3, 3]))
        if jump > cfg.max_speed * dt + 2.0 * cfg.ransac_threshold:
            return f"implausible jump of {jump:.3f} m in {dt:.3f} s"
        turn = _angle(T[:3, :3], prev[:3, :3])
        if turn > cfg.max_angular_speed * dt + math.radians(5.0):
            return f"implausible turn of {math.degrees(turn):.1f} deg in {dt:.3f} s"
        return ""

    def _define_canonical(
        self, record: ObjectRecord, frame: RGBDFrame, gray: np.ndarray, mask: Mask, feats: Features
    ) -> tuple[Pose, AdmissionDecision | None]:
        cfg = self.config
        t = frame.timestamp
        adm = record.gallery.config
        _, valid = lift(feats.keypoints, frame.depth, (0, 0), frame.K, cfg.min_depth, cfg.max_depth)
        n3d = int(valid.sum())
        if mask.area < adm.min_area:
            return Pose(
                t,
                "lost",
                None,
                PoseDiagnostics(reason=f"no canonical frame yet: mask area {mask.area} < {adm.min_area} px"),
            ), None
        if n3d < cfg.min_canonical_points:
            return Pose(
                t,
                "lost",
                None,
                PoseDiagnostics(
                    matches=len(feats),
                    reason=f"no canonical frame yet: {n3d} depth-backed features < {cfg.min_canonical_points}",
                ),
            ), None
        pts = mask_points(frame, mask, cfg.min_depth, cfg.max_depth)
        c0 = np.median(pts, axis=0)
        anchor = to_homogeneous(np.eye(3), -c0)
        decision = record.gallery.set_canonical(frame, gray, mask, feats, anchor)
        if not decision.admitted:
            return Pose(
                t,
                "lost",
                None,
                PoseDiagnostics(reason=f"no canonical frame yet: view rejected ({decision.reason})"),
            ), decision
        diag = PoseDiagnostics(
            matches=len(feats),
            pairs=n3d,
            inliers=n3d,
            rmse=0.0,
            solver="canonical",
            reason="canonical frame defined",
            snapshot=decision.snapshot,
            attempts=0,
        )
        return Pose(t, "estimated", np.linalg.inv(anchor), diag), decision

    def _choose(self, record: ObjectRecord) -> list[Snapshot]:
        anchored = record.gallery.anchored()
        if not anchored:
            return []
        last = record.trajectory.last_valid(1)
        if last and last[0].camera_from_object is not None:
            R = last[0].camera_from_object[:3, :3]
            # anchor = object_from_camera at capture, so its rotation transposed is camera_R_object then
            key = {s.index: _angle(s.anchor[:3, :3].T, R) for s in anchored}  # type: ignore[index]
            order = sorted(anchored, key=lambda s: (key[s.index], -s.index))
        else:
            order = sorted(anchored, key=lambda s: -s.index)
        return order[: self.config.max_snapshots]

    def _correspond(self, snap: Snapshot, feats: Features) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Ratio-test matches with lifted snapshot keypoints: (pairs (M, 2), (M, 3), (M,) valid).

        Pairs are (live index, snapshot index) inside both masks; the snapshot keypoints are
        lifted to 3-D in the snapshot's camera frame, metres.
        """
        empty = np.zeros((0, 2), dtype=np.int64), np.zeros((0, 3)), np.zeros(0, dtype=bool)
        if snap.features is None or len(snap.features) < 2 or len(feats) < 1:
            return empty
        pairs = self.extractor.match(feats, snap.features)
        if len(pairs) == 0:
            return empty
        sk = snap.features.keypoints[pairs[:, 1]]
        x0, y0 = snap.bbox[0], snap.bbox[1]
        u = np.rint(sk[:, 0]).astype(np.int64) - x0
        v = np.rint(sk[:, 1]).astype(np.int64) - y0
        ok = (u >= 0) & (v >= 0) & (u < snap.mask.shape[1]) & (v < snap.mask.shape[0])
        ok[ok] = snap.mask[v[ok], u[ok]]
        pairs = pairs[ok]
        ref_pts, ref_valid = lift(
            snap.features.keypoints[pairs[:, 1]],
            snap.depth,
            (x0, y0),
            snap.K,
            self.config.min_depth,
            self.config.max_depth,
        )
        return pairs, ref_pts, ref_valid

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
