"""The canonical object frame of the pose stage (:mod:`pal.perception.pose`): defined by a first good view.

The first view of an object with enough depth-backed features (``min_canonical_points``) or,
with the dense fit on, enough depth pixels (twice its ``min_points``) on a surface that pins all
six degrees of freedom (:func:`pal.perception.icp.geometric_condition`), and enough area (the
gallery's ``min_area``, or half of it where ``small_canonical_points`` keypoints have depth)
defines its frame: origin at the median 3-D point of that view's mask (m), axes parallel to the
camera axes at that moment. That view becomes the canonical snapshot, anchored with
``object_from_camera = [I, -c0]``.
"""

from __future__ import annotations

import numpy as np

from pal.perception.features import Features
from pal.perception.frames import RGBDFrame
from pal.perception.icp import geometric_condition
from pal.perception.masks import Mask
from pal.perception.memory import AdmissionDecision, ObjectRecord
from pal.perception.pose_config import PoseConfig
from pal.perception.rigid import to_homogeneous
from pal.perception.spatial import lift, mask_points
from pal.perception.trajectory import Pose, PoseDiagnostics

__all__ = ["define_canonical"]


def define_canonical(
    cfg: PoseConfig, record: ObjectRecord, frame: RGBDFrame, gray: np.ndarray, mask: Mask, feats: Features
) -> tuple[Pose, AdmissionDecision | None]:
    """Define the object's canonical frame from this view, if it qualifies (module docstring).

    Args:
        cfg: the pose estimator's parameters.
        record: the object's record; its gallery takes the view as its canonical snapshot.
        frame: the current frame.
        gray: its (H, W) uint8 luminance.
        mask: the object's mask.
        feats: the object's features in this frame.

    Returns:
        (pose, decision): ``estimated`` (``camera_from_object`` = inverse anchor, with the
        origin's covariance) and the snapshot's admission, or ``lost`` with the reason.
    """
    t = frame.timestamp
    adm = record.gallery.config
    _, valid = lift(feats.keypoints, frame.depth, (0, 0), frame.K, cfg.min_depth, cfg.max_depth)
    n3d = int(valid.sum())
    small_ok = 2 * mask.area >= adm.min_area and n3d >= cfg.small_canonical_points
    if mask.area < adm.min_area and not small_ok:
        return Pose(
            t,
            "lost",
            None,
            PoseDiagnostics(
                reason=f"no canonical frame yet: mask area {mask.area} < {adm.min_area} px"
                f" with {n3d} depth-backed features < {cfg.small_canonical_points}"
            ),
        ), None
    pts = mask_points(frame, mask, cfg.min_depth, cfg.max_depth)
    dense = (
        n3d < cfg.min_canonical_points
        and cfg.icp is not None
        and len(pts) >= 2 * cfg.icp.min_points
        and geometric_condition(frame, mask, cfg.icp, cfg.noise) <= cfg.icp.max_condition
    )
    if n3d < cfg.min_canonical_points and not dense:
        return Pose(
            t,
            "lost",
            None,
            PoseDiagnostics(
                matches=len(feats),
                reason=f"no canonical frame yet: {n3d} depth-backed features < {cfg.min_canonical_points}"
                + ("" if cfg.icp is None else " and a surface that depth alone cannot pin"),
            ),
        ), None
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
    # the frame is defined, not measured: no rotation uncertainty; the origin is a median of
    # pts, as uncertain as the sensor's depth there and the points' spread allow
    var = (np.var(pts, axis=0) / max(pts.shape[0], 1)) + float(cfg.noise.sigma(float(c0[2]))) ** 2
    cov = np.diag(np.concatenate([np.full(3, 1e-10), var]))
    return Pose(t, "estimated", np.linalg.inv(anchor), diag, cov), decision
