"""The perceptual pipeline Π (Eq. 4.5): RGB-D frame -> ŝ_vis(t), live or over a recorded sequence.

Per frame: checks (time order, some valid depth) -> segmentation Σ (geometric or oracle; with
``propagation``, only every few frames: in between, the previous masks are carried by the
camera's motion and refined, :mod:`pal.perception.propagation`, and keep their ids) ->
the frame's features, once -> the camera's own motion from the static background
(:mod:`pal.perception.egomotion`) -> association to memory with masks predicted under that
motion, appearance and the fragment rule (stable ids; an object lost for a moment takes its id
back by predicted 3-D position and gallery appearance, :mod:`pal.perception.reid`) -> with
``merge``, pieces that moved rigidly together reported as one object
(:mod:`pal.perception.fragments`) -> for each associated object: spatial
descriptor, pose (optional; a static object's egomotion prediction when the live data confirm
it, :mod:`pal.perception.pose_predicted`, else a fit with world-frame gates and consistency with
the camera's motion) and EEMS admission (skipped for a confirmed prediction; the dense fits of
all objects run at once, :mod:`pal.perception.icp_fit_batch`) -> missing objects get a ``lost`` (or flagged ``propagated``) pose sample ->
relational layer (grounded predicates in the support-plane frame, salience order) -> scene
descriptor (Table 5.6). Each stage's time is in :attr:`PerceptionState.timings`; the state's types
are in :mod:`pal.perception.state`.

Bad input raises a specific error before any state changes: a frame that is not an
:class:`RGBDFrame` (``TypeError``), a frame earlier than the previous one
(:class:`~pal.frames.TimestampOrderError`; equal timestamps are allowed), a frame without a
valid depth pixel (:class:`~pal.frames.EmptyDepthError`).

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
from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np

from pal.frames import TimestampOrderError
from pal.perception.egomotion import CameraMotion, EgoMotion, feature_weights
from pal.perception.features import Features
from pal.perception.filters import OneEuroFilter
from pal.perception.fragments import FragmentMerger
from pal.perception.frames import RGBDFrame
from pal.perception.icp_batch import ScoreItem
from pal.perception.icp_fit_batch import icp_fits
from pal.perception.kinematic import KinematicConfig, KinematicDescriptor, trajectory_descriptor
from pal.perception.masks import Mask
from pal.perception.memory import AdmissionDecision, Gallery, ObjectRecord
from pal.perception.pipeline_config import PipelineConfig
from pal.perception.plane import Plane
from pal.perception.pose import PoseEstimator, position_std
from pal.perception.pose_dense import DenseRequest
from pal.perception.pose_predicted import fit_due, predicted_poses
from pal.perception.propagation import carried_plane, propagate_masks
from pal.perception.regions import metric_area
from pal.perception.reid import gallery_histograms
from pal.perception.relations import SceneRelations, scene_relations
from pal.perception.scene import scene_descriptor
from pal.perception.segmentation import Candidate, GeometricSegmenter, OracleSegmenter
from pal.perception.spatial import SpatialDescriptor, spatial_descriptor
from pal.perception.state import ObjectState, PerceptionState, require_finite_positions
from pal.perception.tracking import Observation, Tracker
from pal.perception.trajectory import Pose, PoseDiagnostics

__all__ = ["ObjectState", "PerceptionState", "Pipeline", "PipelineConfig"]

logger = logging.getLogger(__name__)

@dataclass(eq=False)
class _Pending:
    """An observed object between the phases of its update (:meth:`Pipeline._observe_all`)."""

    obs: Observation
    rec: ObjectRecord
    spatial: SpatialDescriptor | None
    feats: Features | Callable[[], Features]
    pose: Pose | None = None
    decision: AdmissionDecision | None = None
    request: DenseRequest | None = None
    fitted: bool = False  # a fit ran: its outcome updates ``rec.failed_fits`` after the dense phase


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
        seg_seed, pose_seed, ego_seed = np.random.SeedSequence(cfg.seed).spawn(3)
        self.segmenter: GeometricSegmenter | OracleSegmenter
        if cfg.segmenter == "geometric":
            self.segmenter = GeometricSegmenter(cfg.segmentation, np.random.default_rng(seg_seed))
        else:
            self.segmenter = OracleSegmenter(cfg.oracle_background_ids, min_area=cfg.segmentation.min_area)
        self.tracker = Tracker(cfg.tracker)
        self.merger = None if cfg.merge is None else FragmentMerger(cfg.merge)
        self.estimator = PoseEstimator(cfg.pose, np.random.default_rng(pose_seed))
        self.egomotion = (
            None
            if cfg.camera_motion is None
            else EgoMotion(cfg.camera_motion, np.random.default_rng(ego_seed))
        )
        self.records: dict[int, ObjectRecord] = {}
        self.frame_count = 0
        self._filters: dict[int, tuple[str, OneEuroFilter]] = {}
        self._last_time: float | None = None
        self._previous_time: float | None = None
        self._carry: tuple[np.ndarray, list[Candidate], dict[int, Mask]] | None = None
        self._since_full = 0
        self._last_relations: SceneRelations | None = None

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
        """Process one frame (frames must come in non-decreasing timestamp order).

        Raises:
            TypeError: ``frame`` is not an :class:`RGBDFrame`.
            pal.frames.TimestampOrderError: ``frame`` is earlier than the previous frame.
            pal.frames.EmptyDepthError: ``frame`` has no valid depth pixel.
        """
        self._check_frame(frame)
        t = frame.timestamp
        cfg = self.config
        timings: dict[str, float] = {}
        clock = time.perf_counter()
        carry = self._due_carry(t)
        candidates = carry[1] if carry is not None else self.segmenter(frame)
        timings["segmentation"], clock = time.perf_counter() - clock, time.perf_counter()
        gray = frame.gray()
        frame_features = None
        if cfg.estimate_pose or self.egomotion is not None:
            frame_features = self.estimator.extractor.detect(gray)
        timings["features"], clock = time.perf_counter() - clock, time.perf_counter()
        camera = None
        if self.egomotion is not None and frame_features is not None:
            camera = self.egomotion.update(
                frame, frame_features, self._weights(frame, frame_features, candidates)
            )
        timings["camera_motion"], clock = time.perf_counter() - clock, time.perf_counter()
        if carry is not None:
            candidates, carried = self._propagate(frame, carry, camera), True
            if candidates is None:
                candidates, carried = self.segmenter(frame), False
            timings["segmentation"] += time.perf_counter() - clock
            clock = time.perf_counter()
        known = carry is not None and carried
        observations = self.tracker.update(candidates, t, frame=frame, motion=camera, known_ids=known, gallery=self._views)
        self._since_full = self._since_full + 1 if carry is not None and carried else 0
        if self.config.propagation is not None:
            self._carry = (frame.depth, candidates, {o.track_id: o.mask for o in observations})
        if self.merger is not None:
            observations = self.merger.apply(observations)
        timings["tracking"], clock = time.perf_counter() - clock, time.perf_counter()
        predicted = self._predicted(observations, frame, camera)
        t_pose = time.perf_counter() - clock
        states, spent, t_mem = self._observe_all(observations, frame, gray, frame_features, camera, predicted)
        timings["pose"], timings["memory"] = t_pose + spent, t_mem
        clock = time.perf_counter()
        self._add_missing(states, t)
        self._forget(t)
        W = np.eye(4) if camera is None else camera.world_from_camera
        merges = () if self.merger is None else tuple(self.merger.update(self.frame_count, states, W))
        for kept, merged in merges:
            self.records.pop(merged, None)
            logger.info("object %d merged into %d: they move rigidly together", merged, kept)
        support = getattr(self.segmenter, "last_plane", None)
        moved = frozenset(i for i, s in states.items() if s.mask is not None and known and self.merger is None)
        relations = None if cfg.relations is None else self._relations(frame, states, support, moved)
        self._last_relations = relations
        timings["relations"], clock = time.perf_counter() - clock, time.perf_counter()
        self.frame_count += 1
        scene = scene_descriptor(list(self.records.values()), t, self.frame_count, cfg.visible_window_s)
        timings["scene"] = time.perf_counter() - clock
        objects = tuple(states[i] for i in sorted(states))
        require_finite_positions(objects)
        return PerceptionState(t, self.frame_count - 1, objects, scene, relations, timings, camera, support, merges)

    def _due_carry(self, t: float) -> tuple[np.ndarray, list[Candidate], dict[int, Mask]] | None:
        """The previous frame's (depth, candidates, masks by id) when this frame at ``t`` s propagates them, else None."""
        prop = self.config.propagation
        if prop is None or self._carry is None or not isinstance(self.segmenter, GeometricSegmenter):
            return None
        recent = self._previous_time is not None and t - self._previous_time <= prop.max_interval_s
        return self._carry if recent and self._since_full + 1 < prop.every else None

    def _propagate(
        self, frame: RGBDFrame, carry: tuple[np.ndarray, list[Candidate], dict[int, Mask]], camera: CameraMotion | None
    ) -> list[Candidate] | None:
        """The previous masks carried by the camera's motion (None: motion unknown or no mask, segment instead)."""
        assert self.config.propagation is not None and isinstance(self.segmenter, GeometricSegmenter)
        if camera is None or not camera.known or not carry[2] or carry[0].shape != frame.shape:
            return None
        T = camera.current_from_previous
        if not self.config.propagation.small(T):
            return None
        plane = carried_plane(self.segmenter.last_plane, T)
        self.segmenter.last_plane = plane
        seg, fx, fy = self.segmenter, float(frame.K[0, 0]), float(frame.K[1, 1])

        def keep(tid: int, m: Mask) -> float | None:  # a shrunk mask: the segmentation's rules, at most the track's size
            x0, y0, x1, y1 = m.bbox
            size = metric_area(frame.depth[y0:y1, x0:x1], m.crop, fx, fy)
            if m.area >= 0.8 * carry[2][tid].area:
                return size
            tr = self.tracker.tracks.get(tid)
            smallest = min(seg.config.min_size, tr.size if tr is not None and tr.size > 0 else np.inf)
            return size if seg.large_enough(frame, x0, y0, m.crop, size, smallest) else None

        return propagate_masks(carry[2], carry[0], frame, T, plane, self.config.propagation, seg.config, keep)

    def _check_frame(self, frame: RGBDFrame) -> None:
        """Refuse a frame that is not an RGBDFrame, is out of time order or has no depth (:meth:`__call__`)."""
        if not isinstance(frame, RGBDFrame):
            raise TypeError(f"Pipeline expects an RGBDFrame, got {type(frame).__name__}")
        t = frame.timestamp
        if self._last_time is not None and t < self._last_time:
            raise TimestampOrderError(
                f"frame timestamp {t} s is earlier than the previous frame's {self._last_time} s; frames "
                "must come in non-decreasing time order (equal timestamps are allowed)"
            )
        frame.require_depth()
        self._previous_time, self._last_time = self._last_time, t

    def _observe_all(
        self,
        observations: list[Observation],
        frame: RGBDFrame,
        gray: np.ndarray,
        frame_features: Features | None,
        camera: CameraMotion | None,
        predicted: dict[int, Pose | None],
    ) -> tuple[dict[int, ObjectState], float, float]:
        """Update the associated objects: feature poses, then all dense fits at once, then admissions.

        Objects share no state, so this equals updating them one at a time.

        Returns:
            (states by id, seconds spent on poses, seconds on memory).
        """
        pending, t_pose = [], 0.0
        for obs in observations:
            item, spent = self._observe_start(obs, frame, gray, frame_features, camera, predicted.get(obs.track_id))
            pending.append(item)
            t_pose += spent
        clock = time.perf_counter()
        self._dense_phase(pending, frame)
        t_pose += time.perf_counter() - clock
        clock = time.perf_counter()
        states = {p.obs.track_id: self._observe_finish(p, frame, gray, camera) for p in pending}
        return states, t_pose, time.perf_counter() - clock

    def _observe_start(
        self,
        obs: Observation,
        frame: RGBDFrame,
        gray: np.ndarray,
        frame_features: Features | None,
        camera: CameraMotion | None,
        predicted: Pose | None,
    ) -> tuple[_Pending, float]:
        """An associated object's record, spatial descriptor and feature pose (with its dense fit to run).

        ``predicted``: its confirmed egomotion prediction (:meth:`_predicted`), taken as its pose.

        Returns:
            (the object between phases, seconds spent on its pose).
        """
        cfg = self.config
        t = frame.timestamp
        rec = self._record(obs, t)
        spatial = spatial_descriptor(frame, obs.mask, min_depth=cfg.pose.min_depth, max_depth=cfg.pose.max_depth)
        if spatial is not None:
            rec.centroids.append((t, spatial.centroid))
        mask = obs.mask

        def feats_of(mask: Mask = mask) -> Features:
            if frame_features is None:
                return self.estimator.features(gray, mask)
            return self.estimator.extractor.for_mask(frame_features, gray, mask)

        item = _Pending(obs, rec, spatial, feats_of)
        c0 = time.perf_counter()
        if not cfg.estimate_pose:
            return item, 0.0
        item.pose = predicted
        if predicted is None and not fit_due(rec, cfg.pose.retry):
            why = PoseDiagnostics(reason=f"not fitted in this frame: the last {rec.failed_fits} fits failed")
            item.pose, rec.failed_fits = self.estimator.missing(rec, t, why), rec.failed_fits + 1
        elif predicted is None:
            world = None if camera is None else camera.world_from_camera
            item.feats = feats = feats_of()
            item.pose, item.decision = self.estimator.estimate_features(rec, frame, gray, mask, feats, world)
            item.request = self.estimator.dense_request(rec, frame, mask, world, item.pose)
            item.fitted = True
        else:  # the view is where the gallery last saw it: no new snapshot to consider
            item.decision = AdmissionDecision(False, "predicted")
        return item, time.perf_counter() - c0

    def _dense_phase(self, pending: list[_Pending], frame: RGBDFrame) -> None:
        """The dense fits of all objects that need one, at once (:func:`pal.perception.icp_fit_batch.icp_fits`)."""
        todo = [p for p in pending if p.request is not None]
        if todo:
            cfg = self.config.pose
            items = [ScoreItem(r.model, r.prior, r.mask, r.values, r.step) for r in (p.request for p in todo)]
            for p, fit in zip(todo, icp_fits(items, frame, cfg.noise, cfg.icp), strict=True):
                assert p.request is not None
                dense = self.estimator.dense_pose(p.request, fit)
                p.pose = p.pose if dense is None else dense
        for p in pending:
            if p.fitted and p.pose is not None:
                p.rec.failed_fits = 0 if p.pose.source == "estimated" else p.rec.failed_fits + 1

    def _observe_finish(
        self, item: _Pending, frame: RGBDFrame, gray: np.ndarray, camera: CameraMotion | None
    ) -> ObjectState:
        """An object's EEMS admission, trajectory sample and reported position, after its pose."""
        rec, pose, decision, obs = item.rec, item.pose, item.decision, item.obs
        if self.config.estimate_pose:
            assert pose is not None
            if decision is None:
                world = None if camera is None else camera.world_from_camera
                decision = rec.gallery.consider(
                    frame,
                    gray,
                    obs.mask,
                    item.feats,
                    self.estimator.extractor,
                    self.estimator.anchor_for(pose, rec, world, camera is not None and camera.known),
                    novel=not pose.is_valid and rec.gallery.canonical is not None,
                )
            rec.trajectory.append(pose)
            rec.last_pose_diagnostics = pose.diagnostics
        else:
            decision = rec.gallery.consider(frame, gray, obs.mask, item.feats, self.estimator.extractor, None)
        rec.last_decision = decision
        position, std, source = self._position(obs.track_id, frame, pose, item.spatial)
        rest = (position, std, source, len(rec.gallery), decision)
        return ObjectState(obs.track_id, True, obs.status, obs.label, obs.mask, item.spatial, pose, *rest)

    def _predicted(
        self, observations: list[Observation], frame: RGBDFrame, camera: CameraMotion | None
    ) -> dict[int, Pose | None]:
        """The confirmed egomotion predictions of the observed objects with a record, by id (one pass)."""
        seen = [o for o in observations if o.track_id in self.records] if self.config.estimate_pose else []
        W = np.eye(4) if camera is None else camera.world_from_camera
        known = camera is not None and camera.known
        poses = predicted_poses([(self.records[o.track_id], o.mask) for o in seen], frame, W, self.config.pose, known)
        return {o.track_id: p for o, p in zip(seen, poses, strict=True)}

    def _views(self, tid: int) -> list[np.ndarray]:
        """Hue-saturation histograms of the views in object ``tid``'s gallery (re-identification)."""
        snaps = self.records[tid].gallery.snapshots if tid in self.records else []
        return gallery_histograms([s.rgb for s in snaps], [s.mask for s in snaps])

    def _record(self, obs: Observation, t: float) -> ObjectRecord:
        """The record of an observed track (a new one at its birth), updated with the observation."""
        rec = self.records.get(obs.track_id)
        if rec is None:
            rec = ObjectRecord(
                obs.track_id, Gallery(self.config.admission), t, t, obs.mask, obs.label, num_observations=0
            )
            rec.first_frame = self.frame_count
            self.records[obs.track_id] = rec
        rec.last_updated, rec.last_mask, rec.label = t, obs.mask, obs.label
        rec.num_observations += 1
        return rec

    def _add_missing(self, states: dict[int, ObjectState], t: float) -> None:
        """Add the tracked objects not associated in this frame, with a ``lost`` or ``propagated`` pose."""
        for tid in sorted(self.tracker.tracks):
            if tid in states or (self.merger is not None and tid in self.merger.aliases):
                continue
            rec = self.records[tid]
            pose = None
            if self.config.estimate_pose:
                pose = self.estimator.missing(
                    rec, t, PoseDiagnostics(reason="object not detected in this frame")
                )
                rec.trajectory.append(pose)
                rec.last_pose_diagnostics = pose.diagnostics
            self._filters.pop(tid, None)
            states[tid] = ObjectState(
                tid, False, None, rec.label, None, None, pose, None, None, None, len(rec.gallery), None
            )

    def _relations(
        self, frame: RGBDFrame, states: dict[int, ObjectState], support: Plane | None, carried: frozenset[int]
    ) -> SceneRelations:
        """The relational layer over the objects in ``states`` (their centroid histories, salience order).

        Pairs of ``carried`` objects (masks carried from the previous frame) keep the previous
        frame's topology (:mod:`pal.perception.relations`).
        """
        assert self.config.relations is not None
        cents = {tid: self.records[tid].centroids for tid in states}
        histories = {
            i: (np.array([c[0] for c in cs]), np.array([c[1] for c in cs]).reshape(-1, 3)) for i, cs in cents.items()
        }
        return scene_relations(
            frame,
            {i: s.spatial for i, s in states.items()},
            {i: s.mask for i, s in states.items() if s.mask is not None},
            histories,
            self.config.relations,
            support=support,
            salience={i: self._salience(i, frame) for i in states},
            previous=self._last_relations,
            carried=carried,
        )

    def _weights(self, frame: RGBDFrame, features: Features, candidates: list) -> np.ndarray:
        """Camera-motion weight of each frame feature (:func:`pal.perception.egomotion.feature_weights`).

        0 where a moving track was last seen: its pose moved in the world, or faster than 5 cm/s
        between its last two estimates; without a pose, its surface moved 3 cm in the world.
        """
        assert self.config.camera_motion is not None
        moving = []
        for tid, tr in self.tracker.tracks.items():
            rec = self.records.get(tid)
            posed = rec is not None and rec.world_pose is not None
            if (posed and (rec.moving or rec.speed > 0.05)) or (not posed and tr.moving):  # type: ignore[union-attr]
                moving.append(tr.mask)
        masks = [c.mask for c in candidates]
        return feature_weights(
            frame, features.keypoints, masks, moving, self.config.camera_motion.object_weight
        )

    def _salience(self, tid: int, frame: RGBDFrame) -> float:
        """Metric size (m²) x stability (fraction of frames seen since born) x trackedness (2 with a pose)."""
        rec = self.records[tid]
        tr = self.tracker.tracks.get(tid)
        size = tr.size if tr is not None else 0.0
        if size <= 0:
            x0, y0, x1, y1 = rec.last_mask.bbox
            size = metric_area(frame.depth[y0:y1, x0:x1], rec.last_mask.crop, frame.K[0, 0], frame.K[1, 1])
        stability = min(1.0, rec.num_observations / max(self.frame_count - rec.first_frame + 1, 1))
        tracked = 2.0 if rec.trajectory.num_valid > 0 else 1.0
        return size * stability * tracked

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
        horizon, alive = self.config.forget_after_s, set(self.tracker.tracks)
        dead = [i for i, r in self.records.items() if i not in alive and t - r.last_updated > (horizon or 0.0)]
        for tid in dead if horizon is not None else []:
            del self.records[tid]
