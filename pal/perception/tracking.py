"""Association of candidates to object memory (Eq. 4.9-4.11): stable ids, births, deaths, re-identification.

**With a moving camera** (``update(..., frame=frame, motion=motion)``, what the pipeline
does), a track remembers a sparse 3-D sample of its object's surface and the camera pose it
was seen from. Before association, every track's mask is *predicted*: the sample is moved by
the camera's motion since then (:class:`pal.perception.egomotion.CameraMotion`) and projected
(:func:`pal.perception.association.predict_mask`), then shifted by the track's own residual
image velocity (objects that move by themselves). Candidates are compared with these
predictions: compatible when ``IoU >= tau_predicted`` or ``IoM >= tau_iom`` (or, for a
candidate of the track's size within a factor 1.5 and half its appearance tolerance,
``IoU >= tau_predicted / 2``: geometry and appearance together), when their
appearance (hue-saturation histograms) is within ``max_appearance`` (Bhattacharyya), and when
the candidate's metric size is at least ``min_size_ratio`` of the track's: a small fragment
(a leaf of a plant, a piece of a chair cut off by a depth hole) cannot take over a large
object's id, it is born as a new object. The assignment minimises ``-(IoU + 0.001 IoM) +
appearance_weight * distance``.

**Without a frame** (``update(candidates, t)``), the masks alone are compared as follows.

A candidate i and a memory reference j are *compatible* when ``IoU >= tau_iou`` or
``IoM >= tau_iom`` (Eq. 4.9-4.10, against the reference's last stored mask). Among compatible
pairs, a one-to-one assignment maximising the summed IoU (IoM breaks ties) is found by the
Hungarian method (``scipy.optimize.linear_sum_assignment``). With ``predict_s > 0`` a track
is also compared with its last mask shifted by its image velocity (constant velocity of the mask
centroid over the last two observations, for at most ``predict_s`` seconds ahead), and the
better of the two overlaps counts: a fast object (a rolling ball moving a third of its width
per frame) keeps its id, and a static one is compared exactly as before. Association runs in
stages:

0. with ``trust_labels`` (oracle segmentation), a candidate whose label equals a live track's
   label joins that track;
1. candidates against tracks seen in the previous update;
2. re-identification: the remaining candidates against tracks missing for at most
   ``reid_window_s`` seconds (the proof of concept's 2.0 s rule);
2b. with ``reid`` (frame given), the remaining candidates against the tracks missing for at most
   ``reid.max_gap_s`` by predicted 3-D position and memory-gallery appearance
   (:mod:`pal.perception.reid`);
3. every remaining candidate is born as a new track with a fresh id (ids are never reused).

A track missing for longer than ``reid_window_s`` dies: it is no longer associated, and its id
is listed in :attr:`Tracker.dead`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal

import cv2
import numpy as np
from scipy.optimize import linear_sum_assignment

from pal.perception.association import (
    appearance,
    appearance_distances,
    predict_mask,
    surface_sample,
)
from pal.perception.frames import RGBDFrame
from pal.perception.masks import Mask, intersection_area
from pal.perception.regions import metric_area
from pal.perception.reid import ReidConfig, match_lost, world_medians
from pal.perception.segmentation import Candidate

if TYPE_CHECKING:
    from pal.perception.egomotion import CameraMotion

__all__ = ["Observation", "Track", "Tracker", "TrackerConfig", "overlap_matrices"]

Status = Literal["born", "tracked", "reidentified"]


@dataclass(frozen=True)
class TrackerConfig:
    """Association thresholds (proof-of-concept values).

    Attributes:
        tau_iou: IoU acceptance threshold.
        tau_iom: IoM acceptance threshold (auxiliary criterion).
        reid_window_s: a missing track can be re-identified for this long, s; then it dies.
        trust_labels: associate candidates to tracks by equal segmenter label first (oracle).
        predict_s: horizon of the constant-velocity mask prediction, s (0: no prediction).
        tau_predicted: IoU acceptance threshold against a mask predicted under the camera's
            motion (a prediction is coarser than a measured mask).
        max_appearance: pairs whose appearance distance exceeds this are incompatible, in (0, 1].
        appearance_weight: weight of the appearance distance in the assignment cost.
        min_size_ratio: a candidate smaller than this fraction of a track's metric size cannot
            take its id (the fragment rule).
        sample_step: pixel step of the surface sample a track keeps; None: ``max(2, W // 160)``.
        moving_threshold: a track whose surface's median moves this far in the world from where
            it was first seen is *moving* (its features do not count for the camera's motion), m.
        reid: re-identification of lost tracks by predicted 3-D position and gallery
            appearance (:mod:`pal.perception.reid`), or None for the overlap stage alone.
    """

    tau_iou: float = 0.5
    tau_iom: float = 0.9
    reid_window_s: float = 2.0
    trust_labels: bool = False
    predict_s: float = 0.5
    tau_predicted: float = 0.3
    max_appearance: float = 0.6
    appearance_weight: float = 0.5
    min_size_ratio: float = 0.25
    sample_step: int | None = None
    moving_threshold: float = 0.03
    reid: ReidConfig | None = field(default_factory=ReidConfig)

    def __post_init__(self) -> None:
        for name in ("tau_iou", "tau_iom", "tau_predicted", "max_appearance"):
            if not 0 < getattr(self, name) <= 1:
                raise ValueError(f"{name} is {getattr(self, name)}, expected in (0, 1]")
        if not 0 <= self.min_size_ratio < 1 or self.appearance_weight < 0:
            raise ValueError(
                f"min_size_ratio ({self.min_size_ratio}) must be in [0, 1) and appearance_weight ({self.appearance_weight}) >= 0"
            )
        if self.sample_step is not None and self.sample_step < 1:
            raise ValueError(f"sample_step is {self.sample_step}, expected >= 1 pixel or None")
        if not self.reid_window_s >= 0 or not self.predict_s >= 0:
            raise ValueError(
                f"reid_window_s ({self.reid_window_s}) and predict_s ({self.predict_s}) must be >= 0 seconds"
            )


@dataclass(frozen=True)
class Observation:
    """A stabilised object observation [ι_i, b_i, m_i] (Eq. 4.11).

    Attributes:
        track_id: the stable object id ι_i.
        mask: the candidate's mask (its bbox is b_i).
        label: the segmenter's label l̃_i.
        status: ``"born"``, ``"tracked"`` or ``"reidentified"``.
        iou, iom: overlap with the memory reference it was associated to (0 when born).
    """

    track_id: int
    mask: Mask
    label: int
    status: Status
    iou: float = 0.0
    iom: float = 0.0


@dataclass
class Track:
    """Tracker-side state of one memory reference (mutable, owned by the :class:`Tracker`).

    Attributes:
        track_id, mask, label, first_seen, last_seen, hits: as named (times in s).
        velocity: image velocity of the mask centroid beyond what the camera's motion explains,
            pixels/s.
        points: (M, 3) surface sample in the camera frame of the last observation, metres.
        world_from_camera: (4, 4) camera pose of the last observation (world: the first frame).
        size: running metric size of the visible surface, m² (0: unknown).
        appearance: running hue-saturation histogram, or None.
        origin: (3,) world position of the surface sample's median when first seen, or None.
        centre: (3,) its latest world position, or None.
        speed: world speed of that median between the last two observations, m/s.
        world_velocity: (3,) its world velocity between the last two observations, m/s.
        moving: the track's surface has moved more than ``moving_threshold`` in the world.
    """

    track_id: int
    mask: Mask
    label: int
    first_seen: float
    last_seen: float
    hits: int = 1
    velocity: tuple[float, float] = (0.0, 0.0)
    points: np.ndarray | None = None
    world_from_camera: np.ndarray | None = None
    size: float = 0.0
    appearance: np.ndarray | None = None
    origin: np.ndarray | None = None
    centre: np.ndarray | None = None
    speed: float = 0.0
    world_velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    moving: bool = False

    def predicted(self, t: float, horizon: float) -> Mask | None:
        """The last mask shifted by velocity * (t - last_seen), or None for a zero-pixel shift.

        The elapsed time is clipped to ``horizon`` s. The shifted box may leave the image; it
        is only used for overlaps.
        """
        return shifted(self.mask, self.velocity, min(t - self.last_seen, horizon))


def shifted(mask: Mask, velocity: tuple[float, float], dt: float) -> Mask | None:
    """``mask`` moved by ``velocity * dt`` pixels, or None for a zero-pixel shift (box may leave the image)."""
    dx, dy = round(velocity[0] * dt), round(velocity[1] * dt)
    if dx == 0 and dy == 0:
        return None
    x0, y0, x1, y1 = mask.bbox
    return Mask((x0 + dx, y0 + dy, x1 + dx, y1 + dy), mask.crop, mask.image_shape, mask.area)


def _mask_size(frame: RGBDFrame, mask: Mask, fx: float, fy: float) -> float:
    x0, y0, x1, y1 = mask.bbox
    return metric_area(frame.depth[y0:y1, x0:x1], mask.crop, fx, fy)


def overlap_matrices(masks_a: Sequence[Mask], masks_b: Sequence[Mask]) -> tuple[np.ndarray, np.ndarray]:
    """IoU and IoM of every pair: two (len(a), len(b)) float64 matrices.

    Only pairs whose boxes intersect are compared pixel by pixel (the boxes are tested at once).
    """
    iou = np.zeros((len(masks_a), len(masks_b)))
    iom = np.zeros_like(iou)
    if not len(masks_a) or not len(masks_b):
        return iou, iom
    A = np.array([m.bbox for m in masks_a])
    B = np.array([m.bbox for m in masks_b])
    meet = (np.maximum(A[:, None, 0], B[None, :, 0]) < np.minimum(A[:, None, 2], B[None, :, 2])) & (
        np.maximum(A[:, None, 1], B[None, :, 1]) < np.minimum(A[:, None, 3], B[None, :, 3])
    )
    for i, j in zip(*np.nonzero(meet), strict=True):
        a, b = masks_a[i], masks_b[j]
        inter = intersection_area(a, b)
        if inter:
            iou[i, j] = inter / (a.area + b.area - inter)
            iom[i, j] = inter / min(a.area, b.area)
    return iou, iom


class Tracker:
    """Stateful IoU/IoM tracker (module docstring).

    Attributes:
        tracks: live tracks by id (seen within the re-identification window).
        dead: ids of tracks that died, in order of death.
    """

    def __init__(self, config: TrackerConfig | None = None) -> None:
        self.config = config or TrackerConfig()
        self.tracks: dict[int, Track] = {}
        self.dead: list[int] = []
        self._next_id = 1
        self._last_time: float | None = None
        self._seen_before: float | None = None

    def _predicted(self, tr: Track, t: float) -> list[Mask]:
        """The masks ``tr`` is expected at now: under the camera's motion, then with its own velocity."""
        key = (tr.track_id, t)
        if key not in self._predictions:
            self._predictions[key] = self._predict(tr, t)
        return self._predictions[key]

    def _predict(self, tr: Track, t: float) -> list[Mask]:
        frame = self._frame
        if frame is None or tr.points is None or tr.world_from_camera is None:
            return [tr.mask]
        now = np.eye(4) if self._motion is None else self._motion.world_from_camera
        T = np.linalg.inv(now) @ tr.world_from_camera
        pred = predict_mask(tr.points, T, frame.K, frame.shape, self._step(frame))
        if pred is None:
            return []
        out = [pred]
        if self.config.predict_s > 0:
            moved = shifted(pred, tr.velocity, min(t - tr.last_seen, self.config.predict_s))
            if moved is not None:
                out.append(moved)
        return out

    def _step(self, frame: RGBDFrame) -> int:
        return self.config.sample_step or max(2, frame.width // 160)

    def _geometric(
        self, cands: list[int], tracks: list[int], candidates: Sequence[Candidate], t: float
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """IoU and IoM with the predicted masks (the better prediction), and the compatibility."""
        cfg = self.config
        info = self._cand_info
        assert info is not None
        masks = [candidates[i].mask for i in cands]
        preds, owner = [], []
        for c, tid in enumerate(tracks):
            for pred in self._predicted(self.tracks[tid], t):
                preds.append(pred)
                owner.append(c)
        a, b = overlap_matrices(masks, preds)
        iou = np.zeros((len(cands), len(tracks)))
        iom = np.zeros_like(iou)
        for k, c in enumerate(owner):  # per track, the better of its predictions
            better = a[:, k] > iou[:, c]
            iou[better, c], iom[better, c] = a[better, k], b[better, k]
        size = np.array([info[i][0] for i in cands], dtype=np.float64)[:, None]
        track_size = np.array([self.tracks[tid].size for tid in tracks], dtype=np.float64)[None, :]
        cost_app = np.zeros_like(iou)
        seen = [c for c, tid in enumerate(tracks) if self.tracks[tid].appearance is not None]
        if seen:
            cost_app[:, seen] = appearance_distances(
                np.stack([info[i][1] for i in cands]),
                np.stack([self.tracks[tracks[c]].appearance for c in seen]),  # type: ignore[misc]
            )
        fragment = (track_size > 0) & (size < cfg.min_size_ratio * track_size)
        iou[fragment] = iom[fragment] = 0.0  # the fragment rule
        both = (track_size > 0) & (size > 0)
        ratio = np.where(both, size / np.where(track_size > 0, track_size, 1.0), 1.0)
        similar = both & (np.abs(np.log(np.where(ratio > 0, ratio, 1.0))) <= np.log(1.5))
        looks = similar & (cost_app <= cfg.max_appearance / 2)  # same size and look: a weaker overlap will do
        geometric = (
            (iou >= cfg.tau_predicted) | (iom >= cfg.tau_iom) | (looks & (iou >= cfg.tau_predicted / 2))
        )
        ok = geometric & (cost_app <= cfg.max_appearance)
        return iou - cfg.appearance_weight * cost_app, iom, ok

    def _assign(
        self, cands: list[int], tracks: list[int], candidates: Sequence[Candidate], t: float
    ) -> list[tuple[int, int, float, float]]:
        if not cands or not tracks:
            return []
        if self._cand_info is not None:
            gain, iom, ok = self._geometric(cands, tracks, candidates, t)
            if not ok.any():
                return []
            rows, cols = linear_sum_assignment(np.where(ok, -(gain + 1e-3 * iom), 1e3))
            return [
                (cands[r], tracks[c], float(gain[r, c]), float(iom[r, c]))
                for r, c in zip(rows, cols, strict=True)
                if ok[r, c]
            ]
        masks = [candidates[i].mask for i in cands]
        iou, iom = overlap_matrices(masks, [self.tracks[t].mask for t in tracks])
        if self.config.predict_s > 0:
            for c, tid in enumerate(tracks):
                pred = self.tracks[tid].predicted(t, self.config.predict_s)
                if pred is None:
                    continue
                piou, piom = overlap_matrices(masks, [pred])
                better = piou[:, 0] > iou[:, c]
                iou[better, c], iom[better, c] = piou[better, 0], piom[better, 0]
        ok = (iou >= self.config.tau_iou) | (iom >= self.config.tau_iom)
        if not ok.any():
            return []
        cost = np.where(ok, -(iou + 1e-3 * iom), 1e3)
        rows, cols = linear_sum_assignment(cost)
        return [
            (cands[r], tracks[c], float(iou[r, c]), float(iom[r, c]))
            for r, c in zip(rows, cols, strict=True)
            if ok[r, c]
        ]

    def update(
        self,
        candidates: Sequence[Candidate],
        timestamp: float,
        *,
        frame: RGBDFrame | None = None,
        motion: CameraMotion | None = None,
        known_ids: bool = False,
        gallery: Callable[[int], list[np.ndarray]] | None = None,
    ) -> list[Observation]:
        """Associate this frame's candidates; returns one observation per candidate, in input order.

        Args:
            candidates: this frame's segmentation.
            timestamp: s, not earlier than the previous update's.
            frame: the frame; with it, masks are predicted from the tracks' surface samples and
                appearance and size take part (module docstring).
            motion: the camera's motion to this frame (None: the camera is static).
            known_ids: the candidates' labels are live track ids (masks propagated from the
                previous frame): each joins its track; unknown labels go through association.
            gallery: a track id -> the hue-saturation histograms of its memory gallery's views
                (:func:`pal.perception.reid.gallery_histograms`; empty list: none yet).

        Raises:
            ValueError: ``timestamp`` is earlier than the previous update's.
        """
        self._frame, self._motion, self._candidates = frame, motion, candidates
        self._predictions: dict[tuple[int, float], list[Mask]] = {}
        self._cand_info: list[tuple[float, np.ndarray]] | None = None
        if frame is not None:
            hsv = cv2.cvtColor(np.ascontiguousarray(frame.rgb), cv2.COLOR_RGB2HSV)
            fx, fy = float(frame.K[0, 0]), float(frame.K[1, 1])
            self._cand_info = [
                (
                    c.size if c.size > 0 else _mask_size(frame, c.mask, fx, fy),
                    appearance(hsv, c.mask),
                )
                for c in candidates
            ]
        t = float(timestamp)
        if self._last_time is not None and t < self._last_time:
            raise ValueError(f"timestamp {t} s is earlier than the previous update's {self._last_time} s")
        window = self.config.reid_window_s
        for tid in [tid for tid, tr in self.tracks.items() if t - tr.last_seen > window]:
            del self.tracks[tid]
            self.dead.append(tid)
        prev = self._last_time
        self._last_time = t
        result: dict[int, Observation] = {}
        free = list(range(len(candidates)))
        if self.config.trust_labels or known_ids:
            by_label = {(tid if known_ids else tr.label): tid for tid, tr in self.tracks.items()}
            for i in list(free):
                tid = by_label.pop(candidates[i].label, None)
                if tid is not None:
                    self._update_track(tid, candidates, i, t)
                    result[i] = Observation(tid, candidates[i].mask, candidates[i].label, "tracked", 1.0, 1.0)
                    free.remove(i)
        taken = {obs.track_id for obs in result.values()}
        recent = [tid for tid, tr in self.tracks.items() if tr.last_seen == prev and tid not in taken]
        missing = [tid for tid, tr in self.tracks.items() if tr.last_seen != prev and tid not in taken]
        for pool, status in ((recent, "tracked"), (missing, "reidentified")):
            for i, tid, a, b in self._assign(free, pool, candidates, t):
                self._update_track(tid, candidates, i, t)
                result[i] = Observation(tid, candidates[i].mask, candidates[i].label, status, a, b)  # type: ignore[arg-type]
                free.remove(i)
        for i, tid in self._reidentify(free, missing, result, t, gallery):
            self._update_track(tid, candidates, i, t)
            result[i] = Observation(tid, candidates[i].mask, candidates[i].label, "reidentified")
            free.remove(i)
        for i in free:
            tid = self._next_id
            self._next_id += 1
            self.tracks[tid] = Track(tid, candidates[i].mask, candidates[i].label, t, t)
            self._seen_before = None
            self._remember(self.tracks[tid], i)
            result[i] = Observation(tid, candidates[i].mask, candidates[i].label, "born")
        return [result[i] for i in range(len(candidates))]

    def _remember(self, tr: Track, i: int) -> None:
        """Store what the geometric association needs of candidate ``i`` in ``tr``."""
        frame = self._frame
        if frame is None or self._cand_info is None:
            return
        size, hist = self._cand_info[i]
        tr.points = surface_sample(frame, tr.mask, self._step(frame))
        tr.world_from_camera = np.eye(4) if self._motion is None else self._motion.world_from_camera.copy()
        if tr.points is not None and tr.points.shape[0]:
            W = tr.world_from_camera
            here = W[:3, :3] @ np.median(tr.points, axis=0) + W[:3, 3]
            dt = self._last_time - self._seen_before if self._seen_before is not None else 0.0
            if tr.centre is not None and dt > 0:
                tr.world_velocity = (here - tr.centre) / dt
                tr.speed = float(np.linalg.norm(tr.world_velocity))
            tr.centre = here
            if tr.origin is None:
                tr.origin = here
            elif np.linalg.norm(here - tr.origin) > self.config.moving_threshold:
                tr.moving = True
        tr.size = size if tr.size <= 0 else 0.7 * tr.size + 0.3 * size
        tr.appearance = (
            hist if tr.appearance is None else (0.7 * tr.appearance + 0.3 * hist).astype(np.float32)
        )

    def _update_track(self, tid: int, candidates: Sequence[Candidate], i: int, t: float) -> None:
        tr = self.tracks[tid]
        cand = candidates[i]
        self._seen_before = tr.last_seen
        if t > tr.last_seen:
            preds = self._predicted(tr, t) if self._frame is not None else [tr.mask]
            (u0, v0), (u1, v1) = (preds[0] if preds else tr.mask).centroid(), cand.mask.centroid()
            tr.velocity = ((u1 - u0) / (t - tr.last_seen), (v1 - v0) / (t - tr.last_seen))
        tr.mask, tr.label, tr.last_seen, tr.hits = cand.mask, cand.label, t, tr.hits + 1
        self._remember(tr, i)

    def _reidentify(
        self,
        free: list[int],
        missing: list[int],
        result: dict[int, Observation],
        t: float,
        gallery: Callable[[int], list[np.ndarray]] | None,
    ) -> list[tuple[int, int]]:
        """(candidate, track) pairs of the position-and-gallery stage (:mod:`pal.perception.reid`)."""
        cfg, frame, info = self.config.reid, self._frame, self._cand_info
        if cfg is None or frame is None or info is None or not free:
            return []
        taken = {o.track_id for o in result.values()}
        trs = [
            tr
            for tid in missing
            if tid not in taken
            and (tr := self.tracks[tid]).centre is not None
            and tr.appearance is not None
            and t - tr.last_seen <= cfg.max_gap_s
        ]
        if not trs:
            return []
        W = np.eye(4) if self._motion is None else self._motion.world_from_camera
        gaps = np.array([t - tr.last_seen for tr in trs])
        ahead = np.minimum(gaps, cfg.max_gap_s)[:, None]
        predicted = np.stack([tr.centre for tr in trs]) + ahead * np.stack([tr.world_velocity for tr in trs])
        views = [(gallery(tr.track_id) if gallery is not None else []) or [tr.appearance] for tr in trs]
        masks = [self._candidates[i].mask for i in free]
        cand = (
            world_medians(frame, masks, W, self._step(frame)),
            [info[i][1] for i in free],
            [info[i][0] for i in free],
        )
        matches = match_lost(*cand, predicted, views, np.array([tr.size for tr in trs]), gaps, cfg)  # type: ignore[arg-type]
        return [(free[r], trs[c].track_id) for r, c, _, _ in matches]
