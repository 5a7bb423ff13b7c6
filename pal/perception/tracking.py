"""Association of candidates to object memory (Eq. 4.9-4.11): stable ids, births, deaths, re-identification.

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
3. every remaining candidate is born as a new track with a fresh id (ids are never reused).

A track missing for longer than ``reid_window_s`` dies: it is no longer associated, and its id
is listed in :attr:`Tracker.dead`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy.optimize import linear_sum_assignment

from pal.perception.masks import Mask, intersection_area
from pal.perception.segmentation import Candidate

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
    """

    tau_iou: float = 0.5
    tau_iom: float = 0.9
    reid_window_s: float = 2.0
    trust_labels: bool = False
    predict_s: float = 0.5

    def __post_init__(self) -> None:
        for name in ("tau_iou", "tau_iom"):
            if not 0 < getattr(self, name) <= 1:
                raise ValueError(f"{name} is {getattr(self, name)}, expected in (0, 1]")
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
    """Tracker-side state of one memory reference (mutable, owned by the :class:`Tracker`)."""

    track_id: int
    mask: Mask
    label: int
    first_seen: float
    last_seen: float
    hits: int = 1
    velocity: tuple[float, float] = (0.0, 0.0)

    def predicted(self, t: float, horizon: float) -> Mask | None:
        """The last mask shifted by velocity * (t - last_seen), or None for a zero-pixel shift.

        The elapsed time is clipped to ``horizon`` s. The shifted box may leave the image; it
        is only used for overlaps.
        """
        dt = min(t - self.last_seen, horizon)
        dx, dy = round(self.velocity[0] * dt), round(self.velocity[1] * dt)
        if dx == 0 and dy == 0:
            return None
        x0, y0, x1, y1 = self.mask.bbox
        return Mask(
            (x0 + dx, y0 + dy, x1 + dx, y1 + dy), self.mask.crop, self.mask.image_shape, self.mask.area
        )


def overlap_matrices(masks_a: Sequence[Mask], masks_b: Sequence[Mask]) -> tuple[np.ndarray, np.ndarray]:
    """IoU and IoM of every pair: two (len(a), len(b)) float64 matrices."""
    iou = np.zeros((len(masks_a), len(masks_b)))
    iom = np.zeros_like(iou)
    for i, a in enumerate(masks_a):
        for j, b in enumerate(masks_b):
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

    def _assign(
        self, cands: list[int], tracks: list[int], candidates: Sequence[Candidate], t: float
    ) -> list[tuple[int, int, float, float]]:
        if not cands or not tracks:
            return []
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

    def update(self, candidates: Sequence[Candidate], timestamp: float) -> list[Observation]:
        """Associate this frame's candidates; returns one observation per candidate, in input order.

        Raises:
            ValueError: ``timestamp`` is earlier than the previous update's.
        """
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
        if self.config.trust_labels:
            by_label = {tr.label: tid for tid, tr in self.tracks.items()}
            for i in list(free):
                tid = by_label.pop(candidates[i].label, None)
                if tid is not None:
                    self._update_track(tid, candidates[i], t)
                    result[i] = Observation(tid, candidates[i].mask, candidates[i].label, "tracked", 1.0, 1.0)
                    free.remove(i)
        taken = {obs.track_id for obs in result.values()}
        recent = [tid for tid, tr in self.tracks.items() if tr.last_seen == prev and tid not in taken]
        missing = [tid for tid, tr in self.tracks.items() if tr.last_seen != prev and tid not in taken]
        for pool, status in ((recent, "tracked"), (missing, "reidentified")):
            for i, tid, a, b in self._assign(free, pool, candidates, t):
                self._update_track(tid, candidates[i], t)
                result[i] = Observation(tid, candidates[i].mask, candidates[i].label, status, a, b)  # type: ignore[arg-type]
                free.remove(i)
        for i in free:
            tid = self._next_id
            self._next_id += 1
            self.tracks[tid] = Track(tid, candidates[i].mask, candidates[i].label, t, t)
            result[i] = Observation(tid, candidates[i].mask, candidates[i].label, "born")
        return [result[i] for i in range(len(candidates))]

    def _update_track(self, tid: int, cand: Candidate, t: float) -> None:
        tr = self.tracks[tid]
        if t > tr.last_seen:
            (u0, v0), (u1, v1) = tr.mask.centroid(), cand.mask.centroid()
            tr.velocity = ((u1 - u0) / (t - tr.last_seen), (v1 - v0) / (t - tr.last_seen))
        tr.mask, tr.label, tr.last_seen, tr.hits = cand.mask, cand.label, t, tr.hits + 1
