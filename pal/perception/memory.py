"""Object records ω_i = [ι_i, Λ_i, φ_i] (Eq. 4.12) and their EEMS snapshot galleries (Eq. 4.13).

Admission of an observation to the gallery Λ_i checks, in turn (the first failure is the reason):

1. ``area``: mask area >= ``min_area`` pixels (600);
2. ``sharpness``: variance of the Laplacian over the (eroded) mask >= ``min_sharpness``, and
   ``rank``: the view is at least ``rank_tolerance`` (0.5) times as sharp as the sharpest of
   the object's previous ``rank_window - 1`` (4) observations, so a blurred view is not
   admitted next to a sharper one (the proof of concept kept the sharpest of the last 5; a
   strict rank would block admission whenever sharpness declines steadily, e.g. while a
   face turns away);
3. ``redundancy``: MSE >= ``min_mse`` (600, uint8 RGB on 32x32 masked thumbnails) against each
   of the last ``redundancy_window`` (5) snapshots, and at most ``max_feature_matches`` (30)
   ratio-test feature matches with each of them (features are computed only if 1-3a pass).

Capacity is ``capacity`` (K = 100). **Eviction rule**: when full, the non-canonical snapshot whose
nearest neighbour in the gallery (thumbnail MSE, the newcomer included) is closest — the most
redundant — is evicted; ties go to the oldest. The canonical snapshot (the one defining the
object frame, :mod:`pal.perception.pose`) is never evicted.

A snapshot may carry an *anchor*: ``object_from_camera`` at capture time, i.e. the transform from
that snapshot's camera coordinates to the object's canonical frame. Only anchored snapshots are
used for pose estimation.
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np

from pal.perception.features import FeatureExtractor, Features
from pal.perception.frames import RGBDFrame
from pal.perception.masks import Mask
from pal.perception.trajectory import PoseDiagnostics, Trajectory
from pal.perception.visual import gallery_visual_descriptor, visual_descriptor

__all__ = [
    "AdmissionConfig",
    "AdmissionDecision",
    "Gallery",
    "ObjectRecord",
    "Snapshot",
    "sharpness",
    "thumbnail",
]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class AdmissionConfig:
    """EEMS parameters (proof-of-concept values where it had them).

    Attributes:
        min_area: minimum mask area, pixels.
        min_sharpness: minimum Laplacian variance over the mask (gray levels²). Low by default
            (1.0): it only rejects defocused or featureless crops; a smooth one-colour ball scores
            about 3 and must still get snapshots. Relative blur is the rank check's job.
        rank_window: sharpness ranking window (observations, the current one included).
        rank_tolerance: the view's sharpness must be at least this fraction of the sharpest of
            the previous ``rank_window - 1`` observations (1.0: strictly the sharpest; ties pass).
        min_mse: minimum thumbnail MSE (uint8 RGB units²) to each recent snapshot.
        redundancy_window: how many latest snapshots the redundancy checks compare with.
        max_feature_matches: maximum feature matches with each of them.
        capacity: K_eems, maximum snapshots.
        margin: context pixels kept around the mask's box in the snapshot crop.
        thumb_size: thumbnail side, pixels.
    """

    min_area: int = 600
    min_sharpness: float = 1.0
    rank_window: int = 5
    rank_tolerance: float = 0.5
    min_mse: float = 600.0
    redundancy_window: int = 5
    max_feature_matches: int = 30
    capacity: int = 100
    margin: int = 8
    thumb_size: int = 32

    def __post_init__(self) -> None:
        if self.min_area < 1 or self.rank_window < 1 or self.redundancy_window < 1 or self.capacity < 2:
            raise ValueError(
                f"min_area, rank_window, redundancy_window must be >= 1 and capacity >= 2; got {self}"
            )
        if not 0 < self.rank_tolerance <= 1:
            raise ValueError(f"rank_tolerance is {self.rank_tolerance}, expected in (0, 1]")
        if self.min_sharpness < 0 or self.min_mse < 0 or self.max_feature_matches < 0:
            raise ValueError(f"thresholds must be >= 0; got {self}")
        if self.margin < 0 or self.thumb_size < 4:
            raise ValueError(f"margin must be >= 0 and thumb_size >= 4; got {self}")


def sharpness(gray: np.ndarray, mask: Mask) -> float:
    """Variance of the 3x3 Laplacian of ``gray`` (H, W) uint8 over the mask eroded by one pixel.

    The erosion keeps the silhouette's own edge from counting; the whole mask is used if it
    empties the mask.
    """
    x0, y0, x1, y1 = mask.bbox
    h, w = gray.shape
    rx0, ry0, rx1, ry1 = max(0, x0 - 1), max(0, y0 - 1), min(w, x1 + 1), min(h, y1 + 1)
    lap = cv2.Laplacian(gray[ry0:ry1, rx0:rx1], cv2.CV_32F, ksize=1)
    m = mask.region(rx0, ry0, rx1, ry1)
    eroded = cv2.erode(m.view(np.uint8), np.ones((3, 3), np.uint8)).view(bool)
    sel = eroded if eroded.any() else m
    return float(lap[sel].var())


def thumbnail(rgb: np.ndarray, mask: np.ndarray, size: int) -> np.ndarray:
    """(size, size, 3) float32 masked thumbnail of a crop (pixels outside the mask are 0)."""
    masked = np.where(mask[..., None], rgb, 0).astype(np.uint8)
    return cv2.resize(masked, (size, size), interpolation=cv2.INTER_AREA).astype(np.float32)


def _mse(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.mean((a - b) ** 2))


@dataclass(frozen=True, eq=False)
class Snapshot:
    """A retained object view λ_{i,k}.

    Attributes:
        index: admission serial number within the object (0, 1, ...; never reused).
        timestamp: capture time, s.
        bbox: (x0, y0, x1, y1) of the crop in the frame (the mask's box plus ``margin``).
        rgb: (h, w, 3) uint8 crop. depth: (h, w) float32 metres. mask: (h, w) bool.
        K: (3, 3) intrinsics of the full frame.
        sharpness: Laplacian variance.
        features: keypoints (full-frame pixels) and descriptors, or None if never computed.
        anchor: (4, 4) object_from_camera at capture, or None.
        thumb: masked thumbnail for redundancy checks.
        visual: (54,) visual descriptor, computed when first needed (None until then).
        surfaces: its sampled surfaces in the object frame by sampling settings, kept once computed
            (:func:`pal.perception.pose_dense.snapshot_surface`).
    """

    index: int
    timestamp: float
    bbox: tuple[int, int, int, int]
    rgb: np.ndarray
    depth: np.ndarray
    mask: np.ndarray
    K: np.ndarray
    sharpness: float
    features: Features | None
    anchor: np.ndarray | None
    thumb: np.ndarray
    visual: np.ndarray | None = None
    surfaces: dict = field(default_factory=dict, repr=False)

    def visual_vector(self) -> np.ndarray:
        """The (54,) visual descriptor of the snapshot (computed once)."""
        if self.visual is None:
            object.__setattr__(self, "visual", visual_descriptor(self.rgb, self.mask))
        assert self.visual is not None
        return self.visual

    @property
    def area(self) -> int:
        """Object pixels in the snapshot's mask."""
        return int(self.mask.sum())


@dataclass(frozen=True)
class AdmissionDecision:
    """Outcome of :meth:`Gallery.consider`.

    Attributes:
        admitted: whether the view became a snapshot.
        reason: ``"admitted"``, ``"canonical"``, ``"area"``, ``"sharpness"``, ``"rank"``,
            ``"mse"`` or ``"features"``; ``"predicted"`` when Π did not consider the view (its
            pose was the egomotion prediction, :mod:`pal.perception.pose_predicted`).
        snapshot: the new snapshot's index when admitted.
        evicted: index of the evicted snapshot, if any.
    """

    admitted: bool
    reason: str
    snapshot: int | None = None
    evicted: int | None = None


class Gallery:
    """The EEMS gallery Λ_i of one object (module docstring)."""

    def __init__(self, config: AdmissionConfig | None = None) -> None:
        self.config = config or AdmissionConfig()
        self.snapshots: list[Snapshot] = []
        self.canonical: Snapshot | None = None
        self._recent_sharpness: deque[float] = deque(maxlen=max(self.config.rank_window - 1, 1))
        self._serial = 0

    def __len__(self) -> int:
        return len(self.snapshots)

    def anchored(self) -> list[Snapshot]:
        """The snapshots with a known pose (``anchor`` set), in gallery order."""
        return [s for s in self.snapshots if s.anchor is not None]

    def _make(
        self, frame: RGBDFrame, mask: Mask, sharp: float, features: Features | None, anchor: np.ndarray | None
    ) -> Snapshot:
        bx0, by0, bx1, by1 = _padded_bbox(frame, mask, self.config.margin)
        rgb = np.array(frame.rgb[by0:by1, bx0:bx1])
        mcrop = mask.region(bx0, by0, bx1, by1)
        snap = Snapshot(
            index=self._serial,
            timestamp=frame.timestamp,
            bbox=(bx0, by0, bx1, by1),
            rgb=rgb,
            depth=np.array(frame.depth[by0:by1, bx0:bx1]),
            mask=mcrop,
            K=np.array(frame.K),
            sharpness=sharp,
            features=features,
            anchor=None if anchor is None else np.array(anchor, dtype=np.float64),
            thumb=thumbnail(rgb, mcrop, self.config.thumb_size),
        )
        self._serial += 1
        return snap

    def _insert(self, snap: Snapshot) -> int | None:
        evicted = None
        if len(self.snapshots) >= self.config.capacity:
            pool = [*self.snapshots, snap]
            thumbs = np.stack([s.thumb.ravel() for s in pool]).astype(np.float64)
            sq = (thumbs**2).sum(axis=1)
            d = (sq[:, None] + sq[None, :] - 2.0 * thumbs @ thumbs.T) / thumbs.shape[1]
            np.fill_diagonal(d, np.inf)
            nearest = d.min(axis=1)[:-1]
            order = sorted(range(len(self.snapshots)), key=lambda k: (nearest[k], self.snapshots[k].index))
            victim = next(k for k in order if self.snapshots[k] is not self.canonical)
            evicted = self.snapshots.pop(victim).index
        self.snapshots.append(snap)
        return evicted

    def set_canonical(
        self, frame: RGBDFrame, gray: np.ndarray, mask: Mask, features: Features, anchor: np.ndarray
    ) -> AdmissionDecision:
        """Admit the view that defines the object's canonical frame.

        The sharpness rank and redundancy checks are skipped: they would compare with nothing
        useful.
        """
        if self.canonical is not None:
            raise ValueError("the canonical snapshot is already set; it is fixed for the object's lifetime")
        sharp = sharpness(gray, mask)
        self._recent_sharpness.append(sharp)
        snap = self._make(frame, mask, sharp, features, anchor)
        evicted = self._insert(snap)
        self.canonical = snap
        return AdmissionDecision(True, "canonical", snap.index, evicted)

    def consider(
        self,
        frame: RGBDFrame,
        gray: np.ndarray,
        mask: Mask,
        features: Features | Callable[[], Features] | None,
        extractor: FeatureExtractor | None,
        anchor: np.ndarray | None = None,
        novel: bool = False,
    ) -> AdmissionDecision:
        """Run the admission checks on one view and admit it if they pass.

        Args:
            frame: the frame.
            gray: its (H, W) uint8 luminance.
            mask: the object mask.
            features: the view's features, or a callable computing them on demand, or None
                (then the feature-overlap check is skipped).
            extractor: matches features for the overlap check (required if features are given).
            anchor: (4, 4) object_from_camera to store with the snapshot, if the pose is known.
            novel: the view is known not to be redundant (its features failed to match the
                gallery): the redundancy checks (3.) are skipped.
        """
        cfg = self.config
        if mask.area < cfg.min_area:
            return AdmissionDecision(False, "area")
        sharp = sharpness(gray, mask)
        previous = list(self._recent_sharpness)
        self._recent_sharpness.append(sharp)
        if sharp < cfg.min_sharpness:
            return AdmissionDecision(False, "sharpness")
        if previous and sharp < cfg.rank_tolerance * max(previous):
            return AdmissionDecision(False, "rank")
        recent = [] if novel else self.snapshots[-cfg.redundancy_window :]
        if recent:
            bx0, by0, bx1, by1 = _padded_bbox(frame, mask, cfg.margin)
            thumb = thumbnail(frame.rgb[by0:by1, bx0:bx1], mask.region(bx0, by0, bx1, by1), cfg.thumb_size)
            if min(_mse(thumb, s.thumb) for s in recent) < cfg.min_mse:
                return AdmissionDecision(False, "mse")
        feats = features() if callable(features) else features
        if feats is not None and recent:
            if extractor is None:
                raise ValueError("an extractor is needed to match features for the redundancy check")
            for s in recent:
                if (
                    s.features is not None
                    and len(extractor.match(feats, s.features)) > cfg.max_feature_matches
                ):
                    return AdmissionDecision(False, "features")
        snap = self._make(frame, mask, sharp, feats, anchor)
        evicted = self._insert(snap)
        return AdmissionDecision(True, "admitted", snap.index, evicted)

    def visual_descriptor(self) -> np.ndarray | None:
        """Mean 54-d descriptor over the gallery (Eq. 4.20); None when empty."""
        return (
            gallery_visual_descriptor([s.visual_vector() for s in self.snapshots]) if self.snapshots else None
        )


@dataclass
class ObjectRecord:
    """ω_i: the stable id, the gallery and the maintenance metadata φ_i (mutable state).

    Attributes:
        obj_id: ι_i.
        gallery: Λ_i.
        first_seen, last_updated: s.
        last_mask: latest mask.
        label: latest segmenter label.
        num_observations: frames in which the object was associated.
        trajectory: pose samples T_i.
        centroids: recent (timestamp, (3,) centroid in metres) measurements.
        last_pose_diagnostics: diagnostics of the latest pose attempt.
        last_decision: latest admission decision.
        world_pose: (timestamp s, (4, 4) world_from_object) of the latest estimated pose, or
            None (world: the first frame's camera frame).
        world_origin: (4, 4) world_from_object of the first estimated pose, or None.
        moving: the object has moved in the world (it is no longer presumed static).
        first_frame: index of the frame in which the object was born.
        speed: world speed of the pose origin between its last two estimated poses, m/s.
        predicted_run: poses in a row taken from the camera's egomotion (:mod:`pal.perception.pose_predicted`).
        failed_fits: pose fits in a row that gave no ``estimated`` pose, skipped ones included
            (:func:`pal.perception.pose_predicted.fit_due`).
    """

    obj_id: int
    gallery: Gallery
    first_seen: float
    last_updated: float
    last_mask: Mask
    label: int
    num_observations: int = 1
    trajectory: Trajectory = field(default_factory=Trajectory)
    centroids: deque[tuple[float, np.ndarray]] = field(default_factory=lambda: deque(maxlen=64))
    last_pose_diagnostics: PoseDiagnostics | None = None
    last_decision: AdmissionDecision | None = None
    world_pose: tuple[float, np.ndarray] | None = None
    world_origin: np.ndarray | None = None
    moving: bool = False
    first_frame: int = 0
    speed: float = 0.0
    predicted_run: int = 0
    failed_fits: int = 0


def _padded_bbox(frame: RGBDFrame, mask: Mask, margin: int) -> tuple[int, int, int, int]:
    """The mask's bounding box ``(x0, y0, x1, y1)`` grown by ``margin`` pixels, clipped to the frame."""
    x0, y0, x1, y1 = mask.bbox
    return (
        max(0, x0 - margin),
        max(0, y0 - margin),
        min(frame.width, x1 + margin),
        min(frame.height, y1 + margin),
    )
