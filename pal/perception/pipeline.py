"""The perceptual pipeline Π (Eq. 4.5): RGB-D frame -> ŝ_vis(t), live or over a recorded sequence.

Per frame: segmentation Σ (geometric or oracle) -> IoU/IoM association to memory (stable ids)
-> for each associated object: spatial descriptor, pose (optional) and EEMS admission ->
missing objects get a ``lost`` (or flagged ``propagated``) pose sample -> relational layer ->
scene descriptor (Table 5.6).

Usage::

    pipe = Pipeline(PipelineConfig(estimate_pose=True))
    for frame in open_sequence("recording/"):      # or frames from pal.sim's camera, live
        state = pipe(frame)
        state.observations()   # {obj_id: (position (3,) m, std (3,) m)}, only objects with evidence

Reported positions never contain NaN: an object without evidence this frame (not visible, or
no depth) is simply absent from :meth:`PerceptionState.observations` and has
``position = None``.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from pal.perception.features import Features
from pal.perception.filters import OneEuroConfig, OneEuroFilter
from pal.perception.frames import RGBDFrame
from pal.perception.kinematic import KinematicConfig, KinematicDescriptor, trajectory_descriptor
from pal.perception.masks import Mask
from pal.perception.memory import AdmissionConfig, AdmissionDecision, Gallery, ObjectRecord
from pal.perception.pose import PoseConfig, PoseEstimator, position_std
from pal.perception.relations import RelationConfig, SceneRelations, scene_relations
from pal.perception.scene import scene_descriptor
from pal.perception.segmentation import GeometricSegmenter, OracleSegmenter, SegmentationConfig
from pal.perception.spatial import SpatialDescriptor, spatial_descriptor
from pal.perception.tracking import Tracker, TrackerConfig
from pal.perception.trajectory import Pose, PoseDiagnostics

__all__ = ["ObjectState", "PerceptionState", "Pipeline", "PipelineConfig"]

logger = logging.getLogger(__name__)

PositionSource = Literal["pose_then_centroid", "centroid", "pose"]


@dataclass(frozen=True)
class PipelineConfig:
    """Configuration of Π; every stage's config is nested.

    Attributes:
        segmenter: ``"geometric"`` (default) or ``"oracle"`` (reads ``frame.labels``).
        segmentation: geometric segmenter parameters.
        oracle_background_ids: label ids the oracle ignores (0 and e.g. the table).
        tracker: association parameters.
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
        seed: seeds every random choice (plane and Kabsch RANSAC).
    """

    segmenter: Literal["geometric", "oracle"] = "geometric"
    segmentation: SegmentationConfig = field(default_factory=SegmentationConfig)
    oracle_background_ids: tuple[int, ...] = (0,)
    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    admission: AdmissionConfig = field(default_factory=AdmissionConfig)
    estimate_pose: bool = True
    pose: PoseConfig = field(default_factory=PoseConfig)
    relations: RelationConfig | None = field(default_factory=RelationConfig)
    visible_window_s: float = 2.0
    position_source: PositionSource = "pose_then_centroid"
    smoothing: OneEuroConfig | None = None
    forget_after_s: float | None = None
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


@dataclass(frozen=True, eq=False)
class ObjectState:
    """ŝ_i^obj(t) for one remembered object (Eq. 4.7).

    Attributes:
        obj_id: stable id.
        visible: associated in this frame.
        status: ``"born"``, ``"tracked"``, ``"reidentified"``, or None when not visible.
        label: latest segmenter label (the ground-truth id with the oracle segmenter).
        mask: this frame's mask, or None.
        spatial: egocentric spatial descriptor, or None (not visible / no depth).
        pose: this frame's pose sample (estimated / propagated / lost), or None when pose
            estimation is off.
        position: (3,) metres, camera frame, or None (missing — never NaN).
        position_std: (3,) 1-sigma uncertainty, metres, or None.
        position_source: ``"pose"``, ``"centroid"`` or None.
        num_snapshots: EEMS gallery size.
        admission: this frame's EEMS admission decision, or None.
    """

    obj_id: int
    visible: bool
    status: str | None
    label: int
    mask: Mask | None
    spatial: SpatialDescriptor | None
    pose: Pose | None
    position: np.ndarray | None
    position_std: np.ndarray | None
    position_source: str | None
    num_snapshots: int
    admission: AdmissionDecision | None


@dataclass(frozen=True, eq=False)
class PerceptionState:
    """ŝ_vis(t) = ŝ_scene(t) ∪ [ŝ_i^obj(t)] (Eq. 4.6).

    Attributes:
        timestamp: s. frame_index: 0-based frame counter.
        objects: the objects alive in memory (seen within the re-identification window), by id.
        scene: the Table 5.6 descriptor (JSON-compatible dict).
        relations: the relational layer, or None when disabled.
        timings: seconds spent per stage in this frame.
    """

    timestamp: float
    frame_index: int
    objects: tuple[ObjectState, ...]
    scene: dict[str, Any]
    relations: SceneRelations | None
    timings: dict[str, float]

    def object(self, obj_id: int) -> ObjectState:
        """The state of object ``obj_id``; KeyError if it is not in this frame's state."""
        for o in self.objects:
            if o.obj_id == obj_id:
                return o
        raise KeyError(f"object {obj_id} is not in this state; ids are {[o.obj_id for o in self.objects]}")

    def observations(self) -> dict[int, tuple[np.ndarray, np.ndarray]]:
        """``{obj_id: (position (3,), std (3,))}`` in metres, only for objects with evidence now."""
        return {
            o.obj_id: (o.position, o.position_std)
            for o in self.objects
            if o.position is not None and o.position_std is not None
        }

    def to_dict(self) -> dict[str, Any]:
        """JSON-compatible summary: scene descriptor, relations and timings."""
        return {
            "scene": self.scene,
            "relations": None if self.relations is None else self.relations.to_dict(),
            "timings": dict(self.timings),
        }


class Pipeline:
    """Π: call it on each :class:`RGBDFrame` in time order (module docstring).

    Attributes:
        records: every object record ω_i by id (including dead ones unless forgotten).
        frame_count: frames processed.
    """

    def __init__(self, config: PipelineConfig | None = None) -> None:
        self.config = config or PipelineConfig()
        self.reset()

    def reset(self) -> None:
        """Forget everything; the next frame starts a new run (same seed, same results)."""
        cfg = self.config
        seg_seed, pose_seed = np.random.SeedSequence(cfg.seed).spawn(2)
        self.segmenter: GeometricSegmenter | OracleSegmenter
        if cfg.segmenter == "geometric":
            self.segmenter = GeometricSegmenter(cfg.segmentation, np.random.default_rng(seg_seed))
        else:
            self.segmenter = OracleSegmenter(cfg.oracle_background_ids, min_area=cfg.segmentation.min_area)
        self.tracker = Tracker(cfg.tracker)
        self.estimator = PoseEstimator(cfg.pose, np.random.default_rng(pose_seed))
        self.records: dict[int, ObjectRecord] = {}
        self.frame_count = 0
        self._filters: dict[int, tuple[str, OneEuroFilter]] = {}

    def run(self, frames: Iterable[RGBDFrame], progress_bar: bool = False) -> list[PerceptionState]:
        """Process a recorded sequence (any iterable of frames) offline; returns every state."""
        it: Iterable[RGBDFrame] = frames
        if progress_bar:
            from tqdm import tqdm

            it = tqdm(frames, desc="perception", unit="frame")
        return [self(frame) for frame in it]

    def visual_descriptor(self, obj_id: int) -> np.ndarray | None:
        """The object's 54-d appearance descriptor (gallery mean, Eq. 4.20), or None without snapshots."""
        return self.records[obj_id].gallery.visual_descriptor()

    def kinematic_descriptor(self, obj_id: int, config: KinematicConfig | None = None) -> KinematicDescriptor:
        """The object's 90-d motion descriptor from its estimated poses (raises with < 2 of them)."""
        return trajectory_descriptor(self.records[obj_id].trajectory, config)

    def __call__(self, frame: RGBDFrame) -> PerceptionState:
        """Process one frame (frames must come in non-decreasing timestamp order)."""
        if not isinstance(frame, RGBDFrame):
            raise TypeError(f"Pipeline expects an RGBDFrame, got {type(frame).__name__}")
        cfg = self.config
        t = frame.timestamp
        timings: dict[str, float] = {}
        clock = time.perf_counter()
        candidates = self.segmenter(frame)
        timings["segmentation"], clock = time.perf_counter() - clock, time.perf_counter()
        observations = self.tracker.update(candidates, t)
        timings["tracking"], clock = time.perf_counter() - clock, time.perf_counter()
        gray = frame.gray()
        states: dict[int, ObjectState] = {}
        t_pose = t_mem = 0.0
        for obs in observations:
            rec = self.records.get(obs.track_id)
            if rec is None:
                rec = ObjectRecord(
                    obs.track_id, Gallery(cfg.admission), t, t, obs.mask, obs.label, num_observations=0
                )
                self.records[obs.track_id] = rec
            rec.last_updated, rec.last_mask, rec.label = t, obs.mask, obs.label
            rec.num_observations += 1
            spatial = spatial_descriptor(
                frame, obs.mask, min_depth=cfg.pose.min_depth, max_depth=cfg.pose.max_depth
            )
            if spatial is not None:
                rec.centroids.append((t, spatial.centroid))
            pose: Pose | None = None
            c0 = time.perf_counter()
            if cfg.estimate_pose:
                feats = self.estimator.features(gray, obs.mask)
                pose, decision = self.estimator.estimate(rec, frame, gray, obs.mask, feats)
                c1 = time.perf_counter()
                if decision is None:
                    decision = rec.gallery.consider(
                        frame,
                        gray,
                        obs.mask,
                        feats,
                        self.estimator.extractor,
                        self.estimator.anchor_for(pose),
                    )
                rec.trajectory.append(pose)
                rec.last_pose_diagnostics = pose.diagnostics
            else:
                c1 = time.perf_counter()
                mask = obs.mask

                def lazy(mask: Mask = mask) -> Features:
                    return self.estimator.features(gray, mask)

                decision = rec.gallery.consider(frame, gray, obs.mask, lazy, self.estimator.extractor, None)
            t_pose += c1 - c0
            t_mem += time.perf_counter() - c1
            rec.last_decision = decision
            position, std, source = self._position(obs.track_id, frame, pose, spatial)
            states[obs.track_id] = ObjectState(
                obs.track_id,
                True,
                obs.status,
                obs.label,
                obs.mask,
                spatial,
                pose,
                position,
                std,
                source,
                len(rec.gallery),
                decision,
            )
        timings["pose"], timings["memory"] = t_pose, t_mem
        clock = time.perf_counter()
        for tid in sorted(self.tracker.tracks):
            if tid in states:
                continue
            rec = self.records[tid]
            pose = None
            if cfg.estimate_pose:
                pose = self.estimator.missing(
                    rec, t, PoseDiagnostics(reason="object not detected in this frame")
                )
                rec.trajectory.append(pose)
                rec.last_pose_diagnostics = pose.diagnostics
            self._filters.pop(tid, None)
            states[tid] = ObjectState(
                tid, False, None, rec.label, None, None, pose, None, None, None, len(rec.gallery), None
            )
        self._forget(t)
        relations = None
        if cfg.relations is not None:
            histories = {}
            for tid in states:
                cents = self.records[tid].centroids
                histories[tid] = (
                    np.array([c[0] for c in cents]),
                    np.array([c[1] for c in cents]).reshape(-1, 3),
                )
            relations = scene_relations(
                frame,
                {i: s.spatial for i, s in states.items()},
                {i: s.mask for i, s in states.items() if s.mask is not None},
                histories,
                cfg.relations,
            )
        timings["relations"], clock = time.perf_counter() - clock, time.perf_counter()
        self.frame_count += 1
        scene = scene_descriptor(list(self.records.values()), t, self.frame_count, cfg.visible_window_s)
        timings["scene"] = time.perf_counter() - clock
        objects = tuple(states[i] for i in sorted(states))
        for o in objects:
            if o.position is not None and not (
                np.all(np.isfinite(o.position))
                and o.position_std is not None
                and np.all(np.isfinite(o.position_std))
            ):
                raise RuntimeError(
                    f"internal error: object {o.obj_id} has a non-finite position {o.position} / std {o.position_std}"
                )
        return PerceptionState(t, self.frame_count - 1, objects, scene, relations, timings)

    def _position(
        self, tid: int, frame: RGBDFrame, pose: Pose | None, spatial: SpatialDescriptor | None
    ) -> tuple[np.ndarray | None, np.ndarray | None, str | None]:
        src = self.config.position_source
        position = std = source = None
        if src in ("pose_then_centroid", "pose") and pose is not None and pose.is_valid:
            position, std, source = pose.position, position_std(pose, frame.K), "pose"
        elif src in ("pose_then_centroid", "centroid") and spatial is not None:
            position, std, source = spatial.centroid.copy(), np.maximum(spatial.spread, 0.002), "centroid"
        if position is None or source is None:
            self._filters.pop(tid, None)
            return None, None, None
        if self.config.smoothing is not None:
            prev = self._filters.get(tid)
            if prev is None or prev[0] != source:
                prev = (source, OneEuroFilter(self.config.smoothing))
                self._filters[tid] = prev
            last = prev[1].last_time
            if last is None or frame.timestamp > last:
                position = prev[1](position, frame.timestamp)
        return position, std, source

    def _forget(self, t: float) -> None:
        horizon = self.config.forget_after_s
        if horizon is None:
            return
        alive = set(self.tracker.tracks)
        for tid in [i for i, r in self.records.items() if i not in alive and t - r.last_updated > horizon]:
            del self.records[tid]
