"""Correspondences for the pose estimator (:class:`pal.perception.pose.PoseEstimator`).

Which anchored snapshots of an object to match in a frame (the closest in orientation to the
predicted or last estimated pose), and the pairs of live features and snapshot keypoints
lifted to 3-D: ratio-test matches plus, with a predicted pose, the guided matches
(:func:`pal.perception.features.guided_matches`), kept inside both masks; and those pairs of
all the matched snapshots fused in the canonical frame through their anchors (:func:`fuse_pairs`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pal.perception.features import FeatureExtractor, Features, guided_matches
from pal.perception.frames import RGBDFrame
from pal.perception.memory import ObjectRecord, Snapshot
from pal.perception.pose_config import PoseConfig
from pal.perception.spatial import lift

__all__ = ["FeaturePairs", "choose_snapshots", "correspond", "fuse_pairs", "rotation_angle"]


def rotation_angle(Ra: np.ndarray, Rb: np.ndarray) -> float:
    """Angle between two (3, 3) rotations, rad in [0, pi]."""
    c = (np.trace(Ra.T @ Rb) - 1.0) / 2.0
    return float(np.arccos(np.clip(c, -1.0, 1.0)))


def choose_snapshots(
    record: ObjectRecord, max_snapshots: int, prior: np.ndarray | None = None
) -> list[Snapshot]:
    """Up to ``max_snapshots`` anchored snapshots to match, the closest in view to ``prior`` first.

    ``prior`` is the predicted (4, 4) ``camera_from_object``; without it, the last estimated
    one; without either (or on ties), the newest first. The distance of two views is the angle
    between their camera orientations plus the distance between their camera centres in the
    object frame relative to the current one's range (rad): ``angle(R_s^T R) + |c_s - c| / |c|``
    with ``c = -R^T t``, so a camera sliding past an object without turning prefers the
    snapshots taken nearest to where it is now.
    """
    anchored = record.gallery.anchored()
    if not anchored:
        return []
    last = record.trajectory.last_valid(1)
    ref = prior if prior is not None else (last[0].camera_from_object if last else None)
    if ref is not None:
        R = ref[:3, :3]
        centre = -R.T @ ref[:3, 3]
        reach = max(float(np.linalg.norm(centre)), 1e-3)
        # anchor = object_from_camera at capture: its rotation transposed is camera_R_object then,
        # its translation the camera centre in the object frame
        A = np.array([s.anchor for s in anchored])  # (S, 4, 4); rotation_angle of each, at once
        cos = (np.trace(A[:, :3, :3] @ R, axis1=1, axis2=2) - 1.0) / 2.0
        angles = np.arccos(np.clip(cos, -1.0, 1.0)).tolist()
        key = {
            s.index: angles[k] + float(np.sqrt(d.dot(d))) / reach
            for k, (s, d) in enumerate(zip(anchored, A[:, :3, 3] - centre, strict=True))
        }
        order = sorted(anchored, key=lambda s: (key[s.index], -s.index))
    else:
        order = sorted(anchored, key=lambda s: -s.index)
    return order[:max_snapshots]


def correspond(
    extractor: FeatureExtractor,
    cfg: PoseConfig,
    snap: Snapshot,
    feats: Features,
    prior: np.ndarray | None = None,
    frame: RGBDFrame | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Matches with lifted snapshot keypoints: (pairs (M, 2), (M, 3), (M,) valid).

    Pairs are (live index, snapshot index) inside both masks: ``extractor``'s ratio-test
    matches, and with a predicted ``camera_from_object`` ``prior`` the guided matches (module
    docstring); the snapshot keypoints are lifted to 3-D in the snapshot's camera frame, metres.
    """
    empty = np.zeros((0, 2), dtype=np.int64), np.zeros((0, 3)), np.zeros(0, dtype=bool)
    if snap.features is None or len(snap.features) < 2 or len(feats) < 1:
        return empty
    x0, y0 = snap.bbox[0], snap.bbox[1]
    sk = snap.features.keypoints
    u = np.rint(sk[:, 0]).astype(np.int64) - x0
    v = np.rint(sk[:, 1]).astype(np.int64) - y0
    on = (u >= 0) & (v >= 0) & (u < snap.mask.shape[1]) & (v < snap.mask.shape[0])
    on[on] = snap.mask[v[on], u[on]]
    pts, valid = lift(sk, snap.depth, (x0, y0), snap.K, cfg.min_depth, cfg.max_depth)
    pairs = extractor.match(feats, snap.features)
    if prior is not None and frame is not None and feats.kind == "orb" and snap.anchor is not None:
        ref = np.flatnonzero(on & valid)
        cam = (pts[ref] @ snap.anchor[:3, :3].T + snap.anchor[:3, 3]) @ prior[:3, :3].T + prior[:3, 3]
        front = cam[:, 2] > 1e-3
        ref, cam = ref[front], cam[front]
        if ref.size:
            uv = cam[:, :2] / cam[:, 2:3] * np.array([frame.K[0, 0], frame.K[1, 1]]) + frame.K[:2, 2]
            radius = cfg.guide_px * frame.width / 640.0
            g = guided_matches(
                uv,
                snap.features.descriptors[ref],
                feats.keypoints,
                feats.descriptors,
                radius,
                cfg.guide_bits,
            )
            guided = np.stack([g[:, 1], ref[g[:, 0]]], axis=1)
            taken = set(guided[:, 0].tolist())
            rest = pairs[[int(a) not in taken for a in pairs[:, 0]]] if len(pairs) else pairs
            pairs = np.concatenate([guided, rest.reshape(-1, 2)]).astype(np.int64)
    if len(pairs) == 0:
        return empty
    pairs = pairs[on[pairs[:, 1]]]
    return pairs, pts[pairs[:, 1]], valid[pairs[:, 1]]


@dataclass(frozen=True, eq=False)
class FeaturePairs:
    """Object-frame points <-> live keypoints fused over the tried snapshots (:func:`fuse_pairs`).

    ``matches`` counts every match, ``n2`` those with snapshot depth (the pairs) and ``n3`` the
    pairs whose live keypoint has depth too. The arrays (None with fewer than ``min_pairs``
    pairs): ``obj`` (n2, 3) object-frame points, ``img`` (n2, 2) live pixels, ``live3d`` (n2, 3)
    live points (NaN rows without depth), ``owner`` (n2,) the snapshot of each pair.
    """

    matches: int
    n2: int
    obj: np.ndarray | None = None
    img: np.ndarray | None = None
    live3d: np.ndarray | None = None
    owner: np.ndarray | None = None
    n3: int = 0


def fuse_pairs(
    extractor: FeatureExtractor,
    cfg: PoseConfig,
    snaps: list[Snapshot],
    frame: RGBDFrame,
    feats: Features,
    prior: np.ndarray | None,
) -> FeaturePairs:
    """The correspondences of all ``snaps`` fused in the canonical frame through their anchors.

    Args:
        extractor: the estimator's feature extractor.
        cfg: the estimator's parameters.
        snaps: anchored snapshots to match (:func:`choose_snapshots`).
        frame: the live frame.
        feats: the object's live features.
        prior: (4, 4) predicted ``camera_from_object``, or None.
    """
    live_pts, live_valid = lift(feats.keypoints, frame.depth, (0, 0), frame.K, cfg.min_depth, cfg.max_depth)
    obj, live_idx, owner, has3d = [], [], [], []
    for snap in snaps:
        pairs, ref_pts, ref_valid = correspond(extractor, cfg, snap, feats, prior, frame)
        if len(pairs) == 0 or snap.anchor is None:  # choose_snapshots only yields anchored ones
            continue
        anchor = snap.anchor
        obj.append(ref_pts @ anchor[:3, :3].T + anchor[:3, 3])
        live_idx.append(pairs[:, 0])
        owner.append(np.full(len(pairs), snap.index))
        has3d.append(ref_valid)
    matches = int(sum(len(i) for i in live_idx))
    ok = np.concatenate(has3d) if has3d else np.zeros(0, dtype=bool)
    n2 = int(ok.sum())
    if n2 < cfg.min_pairs:
        return FeaturePairs(matches, n2)
    li = np.concatenate(live_idx)[ok]
    return FeaturePairs(
        matches,
        n2,
        np.concatenate(obj)[ok],
        feats.keypoints[li].astype(np.float64),
        np.where(live_valid[li, None], live_pts[li], np.nan),
        np.concatenate(owner)[ok],
        int(live_valid[li].sum()),
    )
