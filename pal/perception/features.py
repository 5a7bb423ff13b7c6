"""Local image features on an object's mask (ORB by default, SIFT optionally) and ratio-test matching.

Features are detected inside the object mask eroded by ``border`` pixels (OpenCV detection mask),
on a region padded by ``margin`` pixels so descriptor patches near the silhouette still fit in
the image. The erosion drops corners on the silhouette itself: there the descriptor patch mixes
the object with whatever lies behind it, so such a corner is not fixed on the object (on a
smooth one-colour ball every ORB corner is a silhouette corner, and matching them would invent
an orientation). Keypoints
are returned in full-image pixel coordinates. Matching is brute force (Hamming for ORB, L2 for
SIFT) with Lowe's ratio test; matches whose keypoints fall outside either mask are dropped.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np

from pal.perception.masks import Mask

__all__ = ["FeatureConfig", "FeatureExtractor", "Features", "in_mask"]


@dataclass(frozen=True)
class FeatureConfig:
    """Feature detection and matching parameters.

    Attributes:
        kind: ``"orb"`` (default, binary, fast) or ``"sift"``.
        n_features: maximum keypoints per object view.
        ratio: Lowe ratio-test threshold (best / second-best distance).
        margin: pixels of context around the mask's box for descriptor patches.
        fast_threshold: ORB's FAST corner threshold (lower finds more corners on weak texture).
        border: keypoints closer than this many pixels to the mask's boundary are not detected
            (0 keeps silhouette corners).
    """

    kind: Literal["orb", "sift"] = "orb"
    n_features: int = 500
    ratio: float = 0.8
    margin: int = 32
    fast_threshold: int = 12
    border: int = 3

    def __post_init__(self) -> None:
        if self.kind not in ("orb", "sift"):
            raise ValueError(f"feature kind {self.kind!r} unknown; expected 'orb' or 'sift'")
        if self.n_features < 1:
            raise ValueError(f"n_features is {self.n_features}, expected >= 1")
        if not 0 < self.ratio < 1:
            raise ValueError(f"ratio is {self.ratio}, expected in (0, 1)")
        if self.margin < 0 or self.fast_threshold < 1 or self.border < 0:
            raise ValueError(
                f"margin ({self.margin}) and border ({self.border}) must be >= 0 and fast_threshold ({self.fast_threshold}) >= 1"
            )


@dataclass(frozen=True, eq=False)
class Features:
    """Keypoints and descriptors of one object view.

    Attributes:
        keypoints: (N, 2) float32 (u, v) full-image pixel coordinates.
        descriptors: (N, 32) uint8 for ORB, (N, 128) float32 for SIFT.
        kind: ``"orb"`` or ``"sift"``.
    """

    keypoints: np.ndarray
    descriptors: np.ndarray
    kind: str

    def __len__(self) -> int:
        return int(self.keypoints.shape[0])


def in_mask(points: np.ndarray, mask: Mask) -> np.ndarray:
    """(N,) bool: which (N, 2) pixel points fall on ``mask`` (nearest pixel)."""
    pts = np.rint(np.asarray(points)).astype(np.int64)
    x0, y0, x1, y1 = mask.bbox
    u, v = pts[:, 0], pts[:, 1]
    ok = (u >= x0) & (u < x1) & (v >= y0) & (v < y1)
    out = np.zeros(pts.shape[0], dtype=bool)
    out[ok] = mask.crop[v[ok] - y0, u[ok] - x0]
    return out


class FeatureExtractor:
    """Detects, describes and matches features (module docstring)."""

    def __init__(self, config: FeatureConfig | None = None) -> None:
        self.config = config or FeatureConfig()
        cfg = self.config
        if cfg.kind == "orb":
            self._detector = cv2.ORB_create(nfeatures=cfg.n_features, fastThreshold=cfg.fast_threshold)
            self._matcher = cv2.BFMatcher(cv2.NORM_HAMMING)
            self._dim, self._dtype = 32, np.uint8
        else:
            self._detector = cv2.SIFT_create(nfeatures=cfg.n_features)
            self._matcher = cv2.BFMatcher(cv2.NORM_L2)
            self._dim, self._dtype = 128, np.float32

    def empty(self) -> Features:
        """No features: (0, 2) keypoints and (0, D) descriptors of this extractor's kind."""
        return Features(np.zeros((0, 2), np.float32), np.zeros((0, self._dim), self._dtype), self.config.kind)

    def __call__(self, gray: np.ndarray, mask: Mask) -> Features:
        """Features of the object ``mask`` in the (H, W) uint8 image ``gray``.

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
        detect_mask = mask.region(rx0, ry0, rx1, ry1).view(np.uint8) * np.uint8(255)
        if cfg.border > 0:
            # zero-padded: the image edge counts as boundary too
            detect_mask = cv2.erode(
                detect_mask,
                np.ones((2 * cfg.border + 1,) * 2, np.uint8),
                borderType=cv2.BORDER_CONSTANT,
                borderValue=0,
            )
        kps, desc = self._detector.detectAndCompute(region, detect_mask)
        if desc is None or not kps:
            return self.empty()
        pts = np.array([kp.pt for kp in kps], dtype=np.float32) + np.array([rx0, ry0], dtype=np.float32)
        keep = in_mask(pts, mask)
        return Features(pts[keep], np.ascontiguousarray(desc[keep].astype(self._dtype)), self.config.kind)

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
