"""The camera's own motion from the static background: features matched frame to frame, PnP.

Every frame, the strongest features of the frame (:meth:`FeatureExtractor.detect`, up to
``max_features``) are lifted to 3-D with their depth and matched (ratio test) with the previous
frame's; when that leaves too few inliers (a wide baseline), every feature of both frames is
matched again. The fit is then refined on **guided matches**: every previous feature with depth
is projected with the fitted motion and matched with the current features within
``guide_px`` pixels of where it should appear (Hamming distance at most ``guide_bits``), and
the motion is re-fitted on all their inliers. The motion
``current_from_previous`` (a point fixed in the world, seen at ``x`` in the previous camera
frame, is at ``T x`` in the current one) is estimated by seeded PnP-RANSAC
(:func:`pal.perception.pnp.pnp_ransac`) from the previous 3-D points to the current pixels,
refined by Levenberg-Marquardt on the inliers. The support plane and the background are what
a moving camera moves against: features on tracks seen moving are left out (weight 0), and
those on object masks (weight ``object_weight`` < 1) are told from the background (weight 1)
for the static-camera decisions below; in a static scene every other feature counts.

Two prior hypotheses are scored beside the random ones: **no motion** and **constant
velocity** (the previous motion again). A static camera is reported as exactly static
(``source="static"``) when no motion explains at least ``static_tolerance`` of what the best
fit explains (weighted inliers), or when the background alone (matches off every object)
agrees with no motion that well: sensor noise never turns into a drifting camera, and a
textured object sliding across a plain table does not move the camera with it. For the same
reason, a static camera stays static while the background offers fewer than twice
``min_inliers`` matches: objects alone never set the camera in motion. With too
few matches the motion is ``"lost"`` and taken as no motion. The camera's pose in the world
frame (the first frame's camera frame) is ``world_from_camera = world_from_camera_prev @
inverse(current_from_previous)``.

**The support plane is static.** With the support plane of both frames given, the previous
plane moved by a motion must land on the current one (within 1.5 degrees and 1.5 cm plus the
motion's own uncertainty). When no motion is consistent with an unmoved plane and the
estimated motion is not, the camera is static: a hand or an object sweeping through the view
cannot drag the camera with it. (When both are consistent, a camera sliding along the table,
the features decide; when neither is, the support changed and the plane says nothing.)

For a static scene, every object's pose then moves by the same ``current_from_previous``:
the tracker predicts masks with it, the pose estimator checks object poses against it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np

from pal.checks import check_float, check_int
from pal.perception.features import Features, guided_matches
from pal.perception.frames import RGBDFrame, backproject
from pal.perception.masks import Mask
from pal.perception.plane import Plane
from pal.perception.pnp import RgbdFit, pnp_ransac, refine_pose, reprojection_errors

__all__ = ["CameraMotion", "EgoMotion", "EgoMotionConfig", "feature_weights"]

MotionSource = Literal["first", "estimated", "static", "lost"]


@dataclass(frozen=True)
class EgoMotionConfig:
    """Camera-motion estimation parameters (module docstring).

    Attributes:
        max_features: the strongest features of a frame used (weighted by where they lie).
        ratio: Lowe ratio-test threshold of the matches.
        min_depth, max_depth: depth accepted for lifting features, metres (far features are
            kept: PnP weighs them by their pixels, not their noisy depth).
        reprojection_px: inlier threshold, pixels at 640 columns (scaled with the width).
        iterations: the most random hypotheses.
        min_inliers: fewer inliers than this: the motion is lost.
        static_tolerance: no motion is kept when it explains at least this fraction of the best
            fit's weighted inliers.
        object_weight: weight of features on object masks (background and support: 1).
        guide_px: search radius of the guided matches, pixels at 640 columns.
        guide_bits: largest Hamming distance of a guided match (ORB: 256 bits).
    """

    max_features: int = 800
    ratio: float = 0.8
    min_depth: float = 0.2
    max_depth: float = 10.0
    reprojection_px: float = 3.0
    iterations: int = 200
    min_inliers: int = 12
    static_tolerance: float = 0.9
    object_weight: float = 0.3
    guide_px: float = 12.0
    guide_bits: int = 64

    def __post_init__(self) -> None:
        check_int("max_features", self.max_features, minimum=8)
        check_float("ratio", self.ratio, 0.0, 1.0, open_low=True)
        if not 0 <= self.min_depth < self.max_depth:
            raise ValueError(f"depth range [{self.min_depth}, {self.max_depth}] m is empty or negative")
        check_float("reprojection_px", self.reprojection_px, 0.0, open_low=True)
        check_int("iterations", self.iterations)
        check_int("min_inliers", self.min_inliers, minimum=4)
        check_float("static_tolerance", self.static_tolerance, 0.0, 1.0, open_low=True)
        check_float("object_weight", self.object_weight, 0.0, 1.0)
        check_float("guide_px", self.guide_px, 0.0)
        check_int("guide_bits", self.guide_bits, minimum=0)


@dataclass(frozen=True, eq=False)
class CameraMotion:
    """The camera's motion since the previous frame.

    Attributes:
        current_from_previous: (4, 4) transform of the previous camera frame into the current
            one, metres (identity when static, first or lost).
        world_from_camera: (4, 4) pose of the current camera in the world (the first frame's
            camera frame).
        source: ``"first"``, ``"estimated"``, ``"static"`` (no motion explains the matches) or
            ``"lost"`` (too few matches or inliers; taken as no motion).
        matches: ratio-test matches with 3-D points in the previous frame.
        inliers: inliers of the accepted hypothesis.
        rmse_px: reprojection RMSE of the inliers, pixels (None without a fit).
        covariance: (6, 6) covariance of (rotation vector rad, translation m) of an estimated
            motion, or None.
        reason: why the motion is what it is.
    """

    current_from_previous: np.ndarray
    world_from_camera: np.ndarray
    source: MotionSource
    matches: int = 0
    inliers: int = 0
    rmse_px: float | None = None
    covariance: np.ndarray | None = None
    reason: str = ""

    @property
    def known(self) -> bool:
        """True when the motion was measured (``estimated`` or ``static``)."""
        return self.source in ("estimated", "static")

    def to_dict(self) -> dict:
        """JSON-compatible summary: source, translation (m), rotation angle (deg), counts."""
        T = self.current_from_previous
        angle = float(np.degrees(np.arccos(np.clip((np.trace(T[:3, :3]) - 1.0) / 2.0, -1.0, 1.0))))
        return {
            "source": self.source,
            "translation": [float(v) for v in T[:3, 3]],
            "rotation_deg": angle,
            "matches": self.matches,
            "inliers": self.inliers,
            "rmse_px": self.rmse_px,
            "reason": self.reason,
        }


class EgoMotion:
    """Estimates the camera's motion frame to frame (module docstring).

    Args:
        config: parameters.
        rng: generator of the RANSAC samples.
    """

    def __init__(self, config: EgoMotionConfig | None = None, rng: np.random.Generator | int = 0) -> None:
        self.config = config or EgoMotionConfig()
        self.rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
        self._matcher: cv2.DescriptorMatcher | None = None
        self.reset()

    def reset(self) -> None:
        """Forget the previous frame and the world frame."""
        self.world_from_camera = np.eye(4)
        self._plane: Plane | None = None
        self._static = False  # a static camera must first be observed
        self._prev: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._velocity = np.eye(4)

    def _select(
        self, frame: RGBDFrame, features: Features, weights: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Features by decreasing weighted strength.

        Returns:
            (pixels (M, 2), 3-D (M, 3) NaN without depth, descriptors, weights); the first
            ``max_features`` are the ones matched first.
        """
        cfg = self.config
        n = len(features)
        strength = np.ones(n) if features.responses is None else features.responses
        order = np.argsort(-strength, kind="stable")  # the strongest first
        order = order[weights[order] > 0]
        kp = features.keypoints[order].astype(np.float64)
        u = np.clip(np.rint(kp[:, 0]).astype(np.int64), 0, frame.width - 1)
        v = np.clip(np.rint(kp[:, 1]).astype(np.int64), 0, frame.height - 1)
        z = frame.depth[v, u].astype(np.float64)
        ok = (z >= cfg.min_depth) & (z <= cfg.max_depth)
        pts = np.full((kp.shape[0], 3), np.nan)
        if ok.any():
            pts[ok] = backproject(kp[ok, 0], kp[ok, 1], z[ok], frame.K)
        return kp, pts, features.descriptors[order], weights[order]

    def _match(self, query: np.ndarray, train: np.ndarray, kind_l2: bool) -> np.ndarray:
        if self._matcher is None:
            self._matcher = cv2.BFMatcher(cv2.NORM_L2 if kind_l2 else cv2.NORM_HAMMING)
        if len(query) < 1 or len(train) < 2:
            return np.zeros((0, 2), np.int64)
        ratio = self.config.ratio
        pairs = [
            (c[0].queryIdx, c[0].trainIdx)
            for c in self._matcher.knnMatch(query, train, k=2)
            if len(c) == 2 and c[0].distance < ratio * c[1].distance
        ]
        return np.array(pairs, dtype=np.int64).reshape(-1, 2)

    def update(
        self,
        frame: RGBDFrame,
        features: Features,
        weights: np.ndarray | None = None,
        plane: Plane | None = None,
    ) -> CameraMotion:
        """The camera's motion from the previous frame to ``frame``.

        Args:
            frame: the current frame.
            features: its features (:meth:`FeatureExtractor.detect`).
            weights: (N,) weight of each feature (0 excludes it); default 1.
            plane: the current frame's support plane, if known (module docstring).
        """
        cfg = self.config
        w = np.ones(len(features)) if weights is None else np.asarray(weights, dtype=np.float64)
        if w.shape != (len(features),):
            raise ValueError(f"weights has shape {w.shape}, expected ({len(features)},) like the features")
        kp, pts, desc, wt = self._select(frame, features, w)
        prev, self._prev = self._prev, (pts, desc, wt)
        prev_plane, self._plane = self._plane, plane
        if prev is None:
            return CameraMotion(np.eye(4), self.world_from_camera.copy(), "first", reason="first frame")
        m = cfg.max_features
        motion = self._estimate(frame, prev, (kp[:m], pts[:m], desc[:m], wt[:m]))
        if motion.source == "lost" and (len(kp) > m or len(prev[0]) > m):
            motion = self._estimate(frame, prev, (kp, pts, desc, wt), limit=None)
        if motion.source == "estimated" and desc.dtype == np.uint8:
            motion = self._guided(frame, prev, (kp, pts, desc, wt), motion)
        if motion.source == "estimated" and prev_plane is not None and plane is not None:
            if _plane_agrees(prev_plane, plane, np.eye(4)) and not _plane_agrees(
                prev_plane, plane, motion.current_from_previous
            ):
                motion = CameraMotion(
                    np.eye(4),
                    motion.world_from_camera,
                    "static",
                    motion.matches,
                    0,
                    None,
                    reason="the support plane did not move; the features' motion moves it",
                )
        self._static = motion.source == "static"
        if motion.source == "lost":
            self._velocity = np.eye(4)
        else:
            self._velocity = motion.current_from_previous
            self.world_from_camera = self.world_from_camera @ np.linalg.inv(motion.current_from_previous)
        return CameraMotion(
            motion.current_from_previous,
            self.world_from_camera.copy(),
            motion.source,
            motion.matches,
            motion.inliers,
            motion.rmse_px,
            motion.covariance,
            motion.reason,
        )

    def _guided(
        self,
        frame: RGBDFrame,
        prev: tuple[np.ndarray, np.ndarray, np.ndarray],
        now: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
        motion: CameraMotion,
    ) -> CameraMotion:
        """Refine an estimated motion on guided matches of every feature (module docstring)."""
        cfg = self.config
        kp, _, desc, _ = now
        prev_pts, prev_desc, _ = prev
        has3d = np.flatnonzero(np.all(np.isfinite(prev_pts), axis=1))
        T = motion.current_from_previous
        cam = prev_pts[has3d] @ T[:3, :3].T + T[:3, 3]
        front = cam[:, 2] > 1e-3
        has3d, cam = has3d[front], cam[front]
        if has3d.size < cfg.min_inliers or kp.shape[0] < cfg.min_inliers:
            return motion
        uv = cam[:, :2] / cam[:, 2:3] * np.array([frame.K[0, 0], frame.K[1, 1]]) + frame.K[:2, 2]
        radius = cfg.guide_px * frame.width / 640.0
        pairs = guided_matches(uv, prev_desc[has3d], kp, desc, radius, cfg.guide_bits)
        qi, ti = pairs[:, 0], pairs[:, 1]
        if qi.size < max(cfg.min_inliers, motion.inliers):
            return motion
        obj, img = prev_pts[has3d[qi]], kp[ti]
        px = cfg.reprojection_px * frame.width / 640.0
        fit = refine_pose(obj, img, frame.K, T, px, cfg.min_inliers)
        if fit is None or fit.num_inliers < motion.inliers:
            return motion
        cov = fit.covariance
        return CameraMotion(
            fit.matrix(),
            motion.world_from_camera,
            "estimated",
            int(qi.size),
            fit.num_inliers,
            fit.rmse,
            cov,
            "PnP on the background, refined on guided matches",
        )

    def _estimate(
        self,
        frame: RGBDFrame,
        prev: tuple[np.ndarray, np.ndarray, np.ndarray],
        now: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
        limit: int | None = -1,
    ) -> CameraMotion:
        """Match the previous frame's features with ``now`` and fit the motion.

        The first ``max_features`` of the previous frame are matched, or all with ``limit=None``.
        """
        cfg = self.config
        kp, pts, desc, wt = now
        prev_pts, prev_desc, prev_w = prev
        if limit is not None:
            prev_pts, prev_desc, prev_w = (
                prev_pts[: cfg.max_features],
                prev_desc[: cfg.max_features],
                prev_w[: cfg.max_features],
            )
        has3d = np.flatnonzero(np.all(np.isfinite(prev_pts), axis=1))
        pairs = self._match(prev_desc[has3d], desc, desc.dtype != np.uint8)
        identity = np.eye(4)
        here = self.world_from_camera
        if len(pairs) < cfg.min_inliers:
            return CameraMotion(
                identity,
                here,
                "lost",
                len(pairs),
                reason=f"{len(pairs)} matches with depth < {cfg.min_inliers}",
            )
        pw = prev_w[has3d[pairs[:, 0]]] * wt[pairs[:, 1]]
        if self._static and int((pw >= 0.999).sum()) < 2 * cfg.min_inliers:
            return CameraMotion(
                identity,
                here,
                "static",
                len(pairs),
                reason=f"{int((pw >= 0.999).sum())} background matches cannot refute a static camera; objects may move",
            )
        obj = prev_pts[has3d[pairs[:, 0]]]
        img = kp[pairs[:, 1]]
        px = cfg.reprojection_px * frame.width / 640.0
        fit = pnp_ransac(
            obj,
            img,
            frame.K,
            rng=self.rng,
            iterations=cfg.iterations,
            reprojection_error=px,
            min_inliers=cfg.min_inliers,
            image_points_3d=pts[pairs[:, 1]],
            hypotheses=(identity, self._velocity),
            weights=(pw > 0).astype(np.float64),
        )
        if fit is None:
            return CameraMotion(
                identity,
                here,
                "lost",
                len(pairs),
                reason=f"no motion with {cfg.min_inliers} inliers among {len(pairs)} matches",
            )
        return self._static_or_moved(frame, obj, img, pw, fit, px)

    def _static_or_moved(
        self, frame: RGBDFrame, obj: np.ndarray, img: np.ndarray, pw: np.ndarray, fit: RgbdFit, px: float
    ) -> CameraMotion:
        """The camera's motion given the fit on the matches ``obj`` <-> ``img`` (pair weights ``pw``).

        ``static`` when no motion (the identity) explains the matches about as well as the fit,
        else the fitted motion.
        """
        cfg = self.config
        identity = np.eye(4)
        here = self.world_from_camera
        err = reprojection_errors(identity, obj, img, frame.K)
        still = err < px
        background = pw >= 0.999  # both ends off every object
        bg_still, bg_moved = int((still & background).sum()), int((fit.inliers & background).sum())
        if float(still.sum()) >= cfg.static_tolerance * float(fit.inliers.sum()) or (
            bg_still >= max(cfg.min_inliers, cfg.static_tolerance * bg_moved)
        ):
            rmse = float(np.sqrt(np.mean(err[still] ** 2))) if still.any() else None
            return CameraMotion(
                identity,
                here,
                "static",
                len(obj),
                int(still.sum()),
                rmse,
                reason="no motion explains the matches",
            )
        cov = fit.covariance
        return CameraMotion(
            fit.matrix(),
            here,
            "estimated",
            len(obj),
            fit.num_inliers,
            fit.rmse,
            cov,
            "PnP on the background",
        )


def _plane_agrees(
    previous: Plane, current: Plane, T: np.ndarray, deg: float = 1.5, metres: float = 0.015
) -> bool:
    """Whether the previous support plane moved by ``T`` (current_from_previous) lands on the current one."""
    n = T[:3, :3] @ previous.normal
    d = previous.offset - float(n @ T[:3, 3])
    angle = float(np.degrees(np.arccos(np.clip(n @ current.normal, -1.0, 1.0))))
    return angle <= deg and abs(d - current.offset) <= metres


def feature_weights(
    frame: RGBDFrame,
    keypoints: np.ndarray,
    objects: Sequence[Mask],
    moving: Sequence[Mask],
    object_weight: float,
) -> np.ndarray:
    """Camera-motion weight of each feature: (N,) float64 from (N, 2) keypoints, pixels.

    1 on the background, ``object_weight`` on ``objects`` (this frame's candidates), 0 on
    ``moving`` (where moving tracks were last seen). Masks are grown by 8 pixels (at 640
    columns): a corner on an object's silhouette moves with the object, not with the background.
    """
    w = np.ones(len(keypoints))
    if len(keypoints) == 0:
        return w
    on = np.zeros(frame.shape, dtype=np.uint8)
    for m in objects:
        x0, y0, x1, y1 = m.bbox
        on[y0:y1, x0:x1] |= m.crop.view(np.uint8)
    for m in moving:
        x0, y0, x1, y1 = m.bbox
        on[y0:y1, x0:x1][m.crop] = 2
    r = max(1, round(8 * frame.width / 640))
    on = cv2.dilate(on, np.ones((2 * r + 1, 2 * r + 1), np.uint8))
    kp = np.rint(keypoints).astype(np.int64)
    cls = on[np.clip(kp[:, 1], 0, frame.height - 1), np.clip(kp[:, 0], 0, frame.width - 1)]
    w[cls == 1] = object_weight
    w[cls == 2] = 0.0
    return w
