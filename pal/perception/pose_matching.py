"""Correspondences for the pose estimator (:class:`pal.perception.pose.PoseEstimator`).

Which anchored snapshots of an object to match in a frame (the closest in orientation to the
predicted or last estimated pose), and the pairs of live features and snapshot keypoints
lifted to 3-D: ratio-test matches plus, with a predicted pose, the guided matches
(:func:`pal.perception.features.guided_matches`), kept inside both masks.
"""

from __future__ import annotations

import numpy as np

from pal.perception.features import FeatureExtractor, Features, guided_matches
from pal.perception.frames import RGBDFrame
from pal.perception.memory import ObjectRecord, Snapshot
from pal.perception.pose_config import PoseConfig
from pal.perception.spatial import lift

__all__ = ["choose_snapshots", "correspond", "rotation_angle"]


def rotation_angle(Ra: np.ndarray, Rb: np.ndarray) -> float:
    """Angle between two (3, 3) rotations, rad in [0, pi]."""
    c = (np.trace(Ra.T @ Rb) - 1.0) / 2.0
    return float(np.arccos(np.clip(c, -1.0, 1.0)))


def choose_snapshots(
    record: ObjectRecord, max_snapshots: int, prior: np.ndarray | None = None
) -> list[Snapshot]:
    """Up to ``max_snapshots`` anchored snapshots to match, the closest in orientation to ``prior`` first.

    ``prior`` is the predicted (4, 4) ``camera_from_object``; without it, the last estimated
    one; without either (or on ties), the newest first.
    """
    anchored = record.gallery.anchored()
    if not anchored:
        return []
    last = record.trajectory.last_valid(1)
    ref = prior if prior is not None else (last[0].camera_from_object if last else None)
    if ref is not None:
        R = ref[:3, :3]
        # anchor = object_from_camera at capture, so its rotation transposed is camera_R_object then
        key = {s.index: rotation_angle(s.anchor[:3, :3].T, R) for s in anchored}  # type: ignore[index]
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
