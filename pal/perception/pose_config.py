"""The parameters of the pose estimator :class:`pal.perception.pose.PoseEstimator`."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from pal.checks import check_float, check_int
from pal.perception.features import FeatureConfig
from pal.perception.icp import IcpConfig
from pal.perception.noise import DepthNoise
from pal.perception.pose_checks import PoseChecks
from pal.perception.pose_filter import PoseFilter

__all__ = ["FitRetry", "PoseConfig", "PredictionCheck"]


@dataclass(frozen=True)
class PredictionCheck:
    """Bounds on which an egomotion prediction is taken as the pose (:mod:`pal.perception.pose_predicted`).

    Attributes:
        refit_every: at most ``refit_every - 1`` predicted poses in a row; then a fit.
        min_agreement: fewest agreeing model points per visible one (the dense fit's or more).
        max_rmse_sigma: largest RMS point-to-plane residual, in sigma_z (the dense fit's or less).
        max_photometric_sigma: largest robust spread of the grey-level residuals, in units of
            the dense fit's grey-level noise.
    """

    refit_every: int = 6
    min_agreement: float = 0.7
    max_rmse_sigma: float = 2.5
    max_photometric_sigma: float = 1.5

    def __post_init__(self) -> None:
        check_int("refit_every", self.refit_every, minimum=1)
        check_float("min_agreement", self.min_agreement, 0.0, 1.0)
        check_float("max_rmse_sigma", self.max_rmse_sigma, 0.0, open_low=True)
        check_float("max_photometric_sigma", self.max_photometric_sigma, 0.0, open_low=True)


@dataclass(frozen=True)
class FitRetry:
    """How often an object whose pose fits keep failing is fitted (:func:`pal.perception.pose_predicted.fit_due`).

    After ``after`` failed fits in a row (no ``estimated`` pose), the object is fitted only on
    every ``every``-th frame until a fit succeeds; on the frames in between it takes the pose
    sample of a missing observation (``propagated`` or ``lost``) without a fit.

    Attributes:
        after: failed fits in a row before fits are spaced out (>= 1).
        every: then one fit every this many frames (>= 1; 1: every frame).
    """

    after: int = 3
    every: int = 2

    def __post_init__(self) -> None:
        check_int("after", self.after, minimum=1)
        check_int("every", self.every, minimum=1)


@dataclass(frozen=True)
class PoseConfig:
    """Pose-estimation parameters.

    Attributes:
        features: feature detector/matcher settings (ORB default).
        min_depth, max_depth: depth accepted for lifting keypoints, metres.
        noise: the depth sensor's noise model (the depth check).
        ransac_threshold: 3-D agreement tolerance of the depth check, metres (1-2 cm).
        ransac_iterations: RANSAC hypotheses.
        min_pairs: object-point/live-pixel pairs needed to try a fit.
        pnp_reprojection_px: inlier threshold, pixels at 640 columns (scaled with the width).
        pnp_confidence: RANSAC confidence.
        max_snapshots: snapshots tried per frame.
        anchor_min_inliers: inliers needed to anchor a new snapshot with the pose.
        min_canonical_points: depth-backed keypoints needed to define the canonical frame.
        small_canonical_points: a mask smaller than the gallery's ``min_area`` (down to half
            of it) defines the canonical frame when this many of its keypoints have depth.
        max_speed: a faster translation in the world frame since the last estimate is
            rejected, m/s ...
        max_angular_speed: ... or a faster rotation, rad/s.
        propagate_s: constant-velocity propagation horizon after the last estimate, s (0: off).
        guide_px: with a predicted pose (the camera's motion applied to the last estimate),
            snapshot features are also matched within this many pixels (at 640 columns) of
            where the prediction puts them (binary features only) ...
        guide_bits: ... at a Hamming distance of at most this many bits.
        checks: the validity checks (:mod:`pal.perception.pose_checks`).
        icp: the dense RGB-D fit (:mod:`pal.perception.icp`) tried when the features give no
            accepted pose for an object presumed static; None: off.
        dense_horizon_s: the dense fit is tried, and a new view anchored where the camera's
            motion puts it, for an object not known to move whose last estimate is at most
            this old, s (at least ``checks.static_horizon_s``); the dense fit starts at the
            egomotion prediction and must pass the static check against it.
        filter: the temporal filter of a static object's accepted pose with the camera's
            egomotion as prior (:mod:`pal.perception.pose_filter`); None: off.
        prediction: when a static object's egomotion prediction is taken as its pose without
            a fit (:mod:`pal.perception.pose_predicted`; needs ``icp``); None: always fit.
        retry: how often an object whose fits keep failing is fitted; None: in every frame.
    """

    features: FeatureConfig = field(default_factory=FeatureConfig)
    min_depth: float = 0.1
    max_depth: float = 6.0
    noise: DepthNoise = DepthNoise()
    ransac_threshold: float = 0.015
    ransac_iterations: int = 128
    min_pairs: int = 6
    pnp_reprojection_px: float = 4.0
    pnp_confidence: float = 0.99
    max_snapshots: int = 3
    anchor_min_inliers: int = 12
    min_canonical_points: int = 8
    small_canonical_points: int = 16
    max_speed: float = 2.0
    max_angular_speed: float = 2.0 * math.pi
    propagate_s: float = 0.5
    guide_px: float = 10.0
    guide_bits: int = 64
    checks: PoseChecks = PoseChecks()
    icp: IcpConfig | None = field(default_factory=IcpConfig)
    dense_horizon_s: float = 1.0
    filter: PoseFilter | None = field(default_factory=PoseFilter)
    prediction: PredictionCheck | None = field(default_factory=PredictionCheck)
    retry: FitRetry | None = field(default_factory=FitRetry)

    def __post_init__(self) -> None:
        if not self.dense_horizon_s >= self.checks.static_horizon_s:
            raise ValueError(
                f"dense_horizon_s is {self.dense_horizon_s} s; expected >= checks.static_horizon_s "
                f"({self.checks.static_horizon_s} s)"
            )
        if not 0 < self.min_depth < self.max_depth:
            raise ValueError(f"depth range [{self.min_depth}, {self.max_depth}] m is invalid")
        if not 0 < self.ransac_threshold <= 0.1:
            raise ValueError(
                f"ransac_threshold is {self.ransac_threshold} m; expected metres in (0, 0.1], e.g. 0.015"
            )
        if self.min_pairs < 6 or self.ransac_iterations < 1 or not self.pnp_reprojection_px > 0:
            raise ValueError(
                f"min_pairs >= 6, ransac_iterations >= 1 and pnp_reprojection_px > 0 are required; got {self}"
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
