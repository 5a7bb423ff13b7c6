"""Local image features (ORB by default, SIFT optionally), per frame or per object mask, and matching.

Two ways to get an object's features:

- :meth:`FeatureExtractor.detect` finds the features of a whole frame once (up to
  ``frame_features``), and :meth:`FeatureExtractor.for_mask` hands each object the ones inside
  its mask; an object left with fewer than ``min_object_features`` (a dark or weakly textured
  one) is detected again in its own crop with a threshold adapted to its contrast;
- ``extractor(gray, mask)`` detects in the object's crop only.

**Contrast-adaptive thresholds.** With ``fast_threshold=None`` (default) ORB's FAST threshold
is ``contrast_fraction`` times the standard deviation of the grey levels of the region it
detects in (the frame, or the object's mask), clipped to [``min_fast``, ``max_fast``]: a
threshold of 12 grey levels finds corners on a bright printed box but almost none on a dark
wooden chair in a dim room.

Features are kept only inside the object mask eroded by ``border`` pixels (detection mask or
test), with ``margin`` pixels of context so descriptor patches near the silhouette still fit in
the image. The erosion drops corners on the silhouette itself: there the descriptor patch mixes
the object with whatever lies behind it, so such a corner is not fixed on the object (on a
smooth one-colour ball every ORB corner is a silhouette corner, and matching them would invent
an orientation). Keypoints are in full-image pixel coordinates. Matching is brute force
(Hamming for ORB, L2 for SIFT) with Lowe's ratio test.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np
from scipy.spatial import cKDTree

from pal.perception.masks import Mask

__all__ = ["FeatureConfig", "FeatureExtractor", "Features", "guided_matches", "in_mask"]

#: Set bits of every byte value (Hamming distances of binary descriptors).
_POPCOUNT = np.array([bin(i).count("1") for i in range(256)], dtype=np.uint8)


@dataclass(frozen=True)
class FeatureConfig:
    """Feature detection and matching parameters.

    Attributes:
        kind: ``"orb"`` (default, binary, fast) or ``"sift"``.
        n_features: maximum keypoints per object view.
        frame_features: maximum keypoints of a whole frame (:meth:`FeatureExtractor.detect`).
        frame_contrast_fraction: the whole frame's adaptive FAST threshold fraction ...
        frame_min_fast: ... and floor (a frame-wide threshold low enough for a dark object
            would find corners in the shading of every smooth one; crops go lower).
        ratio: Lowe ratio-test threshold (best / second-best distance).
        margin: pixels of context around the mask's box for descriptor patches.
        fast_threshold: ORB's FAST corner threshold, grey levels; None: adapted to contrast.
        contrast_fraction: adaptive FAST threshold = this x the region's grey-level std (in an
            object's crop; a whole frame uses ``frame_contrast_fraction``) ...
        min_fast: ... clipped below here ...
        max_fast: ... and above here.
        min_object_features: an object of at least 40 times as many pixels with fewer features
            from the frame's detection is detected again in its crop
            (:meth:`FeatureExtractor.for_mask`).
        border: keypoints closer than this many pixels to the mask's boundary are not kept
            (0 keeps silhouette corners).
    """

    kind: Literal["orb", "sift"] = "orb"
    n_features: int = 500
    frame_features: int = 2000
    ratio: float = 0.8
    margin: int = 32
    fast_threshold: int | None = None
    contrast_fraction: float = 0.2
    frame_contrast_fraction: float = 0.3
    frame_min_fast: int = 8
    min_fast: int = 3
    max_fast: int = 20
    min_object_features: int = 20
    border: int = 3

    def __post_init__(self) -> None:
        if self.kind not in ("orb", "sift"):
            raise ValueError(f"feature kind {self.kind!r} unknown; expected 'orb' or 'sift'")
        if self.n_features < 1 or self.frame_features < 1:
            raise ValueError(
                f"n_features ({self.n_features}) and frame_features ({self.frame_features}) must be >= 1"
            )
        if not 0 < self.ratio < 1:
            raise ValueError(f"ratio is {self.ratio}, expected in (0, 1)")
        if (
            self.margin < 0
            or (self.fast_threshold is not None and self.fast_threshold < 1)
            or self.border < 0
        ):
            raise ValueError(
                f"margin ({self.margin}) and border ({self.border}) must be >= 0 and fast_threshold ({self.fast_threshold}) >= 1"
            )
        if not (1 <= self.min_fast <= self.max_fast) or not self.contrast_fraction > 0:
            raise ValueError(
                f"need 1 <= min_fast ({self.min_fast}) <= max_fast ({self.max_fast}) and contrast_fraction > 0"
            )
        if self.min_object_features < 0:
            raise ValueError(f"min_object_features is {self.min_object_features}, expected >= 0")


@dataclass(frozen=True, eq=False)
class Features:
    """Keypoints and descriptors of one object view.

    Attributes:
        keypoints: (N, 2) float32 (u, v) full-image pixel coordinates.
        descriptors: (N, 32) uint8 for ORB, (N, 128) float32 for SIFT.
        kind: ``"orb"`` or ``"sift"``.
        responses: (N,) float32 corner strengths, or None.
    """

    keypoints: np.ndarray
    descriptors: np.ndarray
    kind: str
    responses: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.keypoints.shape[0])

    def take(self, index: np.ndarray) -> Features:
        """The features at ``index`` (int indices or a bool mask)."""
        responses = None if self.responses is None else self.responses[index]
        return Features(
            self.keypoints[index], np.ascontiguousarray(self.descriptors[index]), self.kind, responses
        )


def in_mask(points: np.ndarray, mask: Mask, crop: np.ndarray | None = None) -> np.ndarray:
    """(N,) bool: which (N, 2) pixel points fall on ``mask`` (nearest pixel).

    Args:
        points: (N, 2) (u, v) pixels.
        mask: the mask.
        crop: optional replacement of ``mask.crop`` inside its box (e.g. an eroded crop).
    """
    pts = np.rint(np.asarray(points)).astype(np.int64).reshape(-1, 2)
    x0, y0, x1, y1 = mask.bbox
    u, v = pts[:, 0], pts[:, 1]
    ok = (u >= x0) & (u < x1) & (v >= y0) & (v < y1)
    out = np.zeros(pts.shape[0], dtype=bool)
    out[ok] = (mask.crop if crop is None else crop)[v[ok] - y0, u[ok] - x0]
    return out


def _hamming(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamming distances (N,) int32 of (N, D) uint8 binary descriptors, row by row."""
    x = np.bitwise_xor(np.ascontiguousarray(a), np.ascontiguousarray(b))
    if x.shape[1] % 8 == 0:  # 64 bits at a time
        return np.bitwise_count(x.view(np.uint64)).sum(axis=1, dtype=np.int32)
    return _POPCOUNT[x].sum(axis=1, dtype=np.int32)


def guided_matches(
    predicted: np.ndarray,
    descriptors: np.ndarray,
    keypoints: np.ndarray,
    live_descriptors: np.ndarray,
    radius: float,
    max_bits: int,
    candidates: int = 4,
) -> np.ndarray:
    """Matches of binary descriptors searched only near where each should appear.

    Each reference feature, expected at ``predicted`` pixels, is matched with the closest (in
    Hamming distance, at most ``max_bits``) of the ``candidates`` live features nearest to that
    spot within ``radius`` pixels; each live feature is used once (by its closest reference).

    Args:
        predicted: (M, 2) expected pixels of the reference features.
        descriptors: (M, 32) uint8 reference descriptors.
        keypoints: (N, 2) live keypoints, pixels.
        live_descriptors: (N, 32) uint8 live descriptors.
        radius: search radius, pixels.
        max_bits: largest Hamming distance of a match (of 256 bits).
        candidates: live features examined per reference feature.

    Returns:
        (P, 2) int64 index pairs ``(reference index, live index)``.
    """
    empty = np.zeros((0, 2), np.int64)
    if len(predicted) == 0 or len(keypoints) == 0:
        return empty
    k = min(candidates, len(keypoints))
    dist_px, near = cKDTree(keypoints).query(predicted, k=k, distance_upper_bound=radius)
    dist_px, near = dist_px.reshape(len(predicted), k), near.reshape(len(predicted), k)
    found = np.isfinite(dist_px)
    qi = np.nonzero(found)[0]
    ti = near[found]
    if qi.size == 0:
        return empty
    dist = _hamming(descriptors[qi], live_descriptors[ti])
    ok = dist <= max_bits
    qi, ti, dist = qi[ok], ti[ok], dist[ok]
    if qi.size == 0:
        return empty
    order = np.lexsort((dist, qi))
    qi, ti, dist = qi[order], ti[order], dist[order]
    first = np.r_[True, qi[1:] != qi[:-1]]  # the closest candidate of each reference feature
    qi, ti, dist = qi[first], ti[first], dist[first]
    order = np.lexsort((dist, ti))
    qi, ti = qi[order], ti[order]
    first = np.r_[True, ti[1:] != ti[:-1]]  # each live feature once
    return np.stack([qi[first], ti[first]], axis=1).astype(np.int64)


def _eroded(mask: Mask, border: int) -> np.ndarray:
    """The mask's crop eroded by ``border`` pixels (outside the crop, and the image edge, is boundary)."""
    if border <= 0:
        return mask.crop
    k = np.ones((2 * border + 1,) * 2, np.uint8)
    out = cv2.erode(mask.crop.view(np.uint8), k, borderType=cv2.BORDER_CONSTANT, borderValue=0)
    return out.view(bool)


class FeatureExtractor:
    """Detects, describes and matches features (module docstring)."""

    def __init__(self, config: FeatureConfig | None = None) -> None:
        self.config = config or FeatureConfig()
        cfg = self.config
        start = cfg.fast_threshold or cfg.max_fast
        if cfg.kind == "orb":
            self._detector = cv2.ORB_create(nfeatures=cfg.n_features, fastThreshold=start)
            self._frame_detector = cv2.ORB_create(nfeatures=cfg.frame_features, fastThreshold=start)
            self._matcher = cv2.BFMatcher(cv2.NORM_HAMMING)
            self._dim, self._dtype = 32, np.uint8
        else:
            self._detector = cv2.SIFT_create(nfeatures=cfg.n_features)
            self._frame_detector = cv2.SIFT_create(nfeatures=cfg.frame_features)
            self._matcher = cv2.BFMatcher(cv2.NORM_L2)
            self._dim, self._dtype = 128, np.float32

    def empty(self) -> Features:
        """No features: (0, 2) keypoints and (0, D) descriptors of this extractor's kind."""
        return Features(np.zeros((0, 2), np.float32), np.zeros((0, self._dim), self._dtype), self.config.kind)

    def fast_threshold(self, values: np.ndarray, frame: bool = False) -> int:
        """The FAST threshold for a region (``frame``: a whole frame) with these grey levels."""
        cfg = self.config
        if cfg.fast_threshold is not None:
            return cfg.fast_threshold
        std = float(np.std(values)) if values.size else 0.0
        f, lo = (
            (cfg.frame_contrast_fraction, cfg.frame_min_fast)
            if frame
            else (cfg.contrast_fraction, cfg.min_fast)
        )
        return int(np.clip(round(f * std), lo, max(lo, cfg.max_fast)))

    def _run(
        self, detector: cv2.Feature2D, image: np.ndarray, mask: np.ndarray | None, threshold: int
    ) -> tuple:
        if self.config.kind == "orb":
            detector.setFastThreshold(int(threshold))
        return detector.detectAndCompute(image, mask)

    def _pack(self, kps: list, desc: np.ndarray | None, offset: tuple[int, int]) -> Features:
        if desc is None or not kps:
            return self.empty()
        pts = np.array([kp.pt for kp in kps], dtype=np.float32) + np.array(offset, dtype=np.float32)
        resp = np.array([kp.response for kp in kps], dtype=np.float32)
        return Features(pts, np.ascontiguousarray(desc.astype(self._dtype)), self.config.kind, resp)

    def detect(self, gray: np.ndarray) -> Features:
        """Features of a whole (H, W) uint8 frame, threshold adapted to the frame's contrast."""
        if gray.ndim != 2 or gray.dtype != np.uint8:
            raise ValueError(f"gray has shape {gray.shape} dtype {gray.dtype}, expected (H, W) uint8")
        sample = gray[::4, ::4]
        thr = self.fast_threshold(sample, frame=True)
        kps, desc = self._run(self._frame_detector, gray, None, thr)
        return self._pack(kps, desc, (0, 0))

    def for_mask(self, frame_features: Features, gray: np.ndarray, mask: Mask) -> Features:
        """The object's features: the frame's inside its eroded mask, or detected again in its crop.

        The crop is detected again (threshold adapted to the mask's contrast) when the frame's
        detection left fewer than ``min_object_features`` inside the mask, and kept if it
        finds more.
        """
        cfg = self.config
        inside = in_mask(frame_features.keypoints, mask, _eroded(mask, cfg.border))
        feats = frame_features.take(inside)
        if len(feats) >= cfg.min_object_features or mask.area < 40 * cfg.min_object_features:
            return feats
        again = self(gray, mask)
        return again if len(again) > len(feats) else feats

    def __call__(self, gray: np.ndarray, mask: Mask) -> Features:
        """Features of the object ``mask`` in the (H, W) uint8 image ``gray`` (detected in its crop).

        Raises:
            ValueError: ``gray`` is not (H, W) uint8 of the mask's image size.
        """
        if gray.ndim != 2 or gray.dtype != np.uint8:
            raise ValueError(f"gray has shape {gray.shape} dtype {gray.dtype}, expected (H, W) uint8")
        if gray.shape != mask.image_shape:
            raise ValueError(f"gray has shape {gray.shape} but the mask lives in {mask.image_shape}")
        cfg = self.config
        m = cfg.margin
        h, w = gray.shape
        x0, y0, x1, y1 = mask.bbox
        rx0, ry0, rx1, ry1 = max(0, x0 - m), max(0, y0 - m), min(w, x1 + m), min(h, y1 + m)
        region = np.ascontiguousarray(gray[ry0:ry1, rx0:rx1])
        detect_mask = np.zeros((ry1 - ry0, rx1 - rx0), np.uint8)
        detect_mask[y0 - ry0 : y1 - ry0, x0 - rx0 : x1 - rx0] = _eroded(mask, cfg.border).view(
            np.uint8
        ) * np.uint8(255)
        thr = self.fast_threshold(gray[y0:y1, x0:x1][mask.crop])
        kps, desc = self._run(self._detector, region, detect_mask, thr)
        feats = self._pack(kps, desc, (rx0, ry0))
        return feats.take(in_mask(feats.keypoints, mask))

    def match(self, query: Features, train: Features) -> np.ndarray:
        """Ratio-test matches of ``query`` against ``train``.

        Returns:
            (M, 2) int64 index pairs ``(query index, train index)``; empty when either side has
            fewer than 2 features (the ratio test needs a second-best neighbour).

        Raises:
            ValueError: the two feature sets are of different kinds.
        """
        if query.kind != train.kind:
            raise ValueError(f"cannot match {query.kind} features against {train.kind} features")
        if len(query) < 1 or len(train) < 2:
            return np.zeros((0, 2), dtype=np.int64)
        pairs = []
        ratio = self.config.ratio
        for cand in self._matcher.knnMatch(query.descriptors, train.descriptors, k=2):
            if len(cand) == 2 and cand[0].distance < ratio * cand[1].distance:
                pairs.append((cand[0].queryIdx, cand[0].trainIdx))
        return np.array(pairs, dtype=np.int64).reshape(-1, 2)
