"""The configuration of the perceptual pipeline Π (:mod:`pal.perception.pipeline`): every stage's settings, nested."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from pal.perception.egomotion import EgoMotionConfig
from pal.perception.filters import OneEuroConfig
from pal.perception.fragments import MergeConfig
from pal.perception.memory import AdmissionConfig
from pal.perception.pose import PoseConfig
from pal.perception.propagation import PropagationConfig
from pal.perception.relations import RelationConfig
from pal.perception.segmentation import SegmentationConfig
from pal.perception.tracking import TrackerConfig

__all__ = ["PipelineConfig", "PositionSource"]

PositionSource = Literal["pose_then_centroid", "centroid", "pose"]


@dataclass(frozen=True)
class PipelineConfig:
    """Configuration of Π; every stage's config is nested.

    Attributes:
        segmenter: ``"geometric"`` (default) or ``"oracle"`` (reads ``frame.labels``).
        segmentation: geometric segmenter parameters.
        propagation: between full segmentations, carry the previous masks by the camera's
            motion and refine them (:mod:`pal.perception.propagation`; geometric segmenter
            only), or None to segment every frame.
        oracle_background_ids: label ids the oracle ignores (0 and e.g. the table).
        tracker: association parameters.
        camera_motion: camera-motion estimation, or None for a camera known to be static
            (no features are matched between frames then).
        admission: EEMS parameters.
        estimate_pose: run pose estimation (off: faster; no trajectories).
        pose: pose-estimation parameters.
        relations: relational-layer parameters, or None to skip that layer.
        visible_window_s: an object counts as visible in the scene descriptor if seen this recently, s.
        position_source: what the reported object position is: ``"pose_then_centroid"`` (the
            estimated pose's origin when this frame's pose is estimated, else the mask's depth
            centroid), ``"centroid"`` or ``"pose"`` (only estimated poses). Note that the pose
            origin is a point fixed on the object, the centroid is that of the visible surface.
        smoothing: a 1€ filter on reported positions (reset when their source changes), or None.
        forget_after_s: drop records dead for longer than this, s (None: keep all).
        merge: merge fragments that move rigidly together (:mod:`pal.perception.fragments`;
            needs ``estimate_pose``), or None (default) to keep them apart.
        seed: seeds every random choice (plane, camera-motion and pose RANSAC).
    """

    segmenter: Literal["geometric", "oracle"] = "geometric"
    segmentation: SegmentationConfig = field(default_factory=SegmentationConfig)
    propagation: PropagationConfig | None = field(default_factory=PropagationConfig)
    oracle_background_ids: tuple[int, ...] = (0,)
    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    camera_motion: EgoMotionConfig | None = field(default_factory=EgoMotionConfig)
    admission: AdmissionConfig = field(default_factory=AdmissionConfig)
    estimate_pose: bool = True
    pose: PoseConfig = field(default_factory=PoseConfig)
    relations: RelationConfig | None = field(default_factory=RelationConfig)
    visible_window_s: float = 2.0
    position_source: PositionSource = "pose_then_centroid"
    smoothing: OneEuroConfig | None = None
    forget_after_s: float | None = None
    merge: MergeConfig | None = None
    seed: int = 0

    def __post_init__(self) -> None:
        if self.segmenter not in ("geometric", "oracle"):
            raise ValueError(f"segmenter {self.segmenter!r} unknown; expected 'geometric' or 'oracle'")
        if self.position_source not in ("pose_then_centroid", "centroid", "pose"):
            raise ValueError(f"position_source {self.position_source!r} unknown")
        if not self.visible_window_s >= 0 or (
            self.forget_after_s is not None and not self.forget_after_s >= 0
        ):
            raise ValueError("visible_window_s and forget_after_s must be >= 0 seconds")
