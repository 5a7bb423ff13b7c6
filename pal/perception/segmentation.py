"""Segmentation Σ (Eq. 4.8): candidate object instances [l̃_i, b̃_i, m̃_i] from one RGB-D frame.

Two segmenters share the interface ``segmenter(frame) -> list[Candidate]``:

- :class:`GeometricSegmenter` (default, no learned weights): fit the support plane by RANSAC
  on a subsampled back-projection, keep valid pixels that rise more than ``min_height`` above
  it, label its 4-connected components, split each at depth discontinuities (computed inside
  the component's box only, which is what keeps 640x480 frames fast) and drop pieces below
  ``min_area`` pixels. With ``track_plane`` the previous frame's plane is kept (refined by
  least squares) while it still explains the sampled points as well as when it was fitted, so
  RANSAC runs only when the support changes.
- :class:`OracleSegmenter`: one candidate per ground-truth id in ``frame.labels`` (e.g.
  MuJoCo segmentation), for ablations and evaluation.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage

from pal.perception.frames import RGBDFrame, backproject
from pal.perception.masks import Mask
from pal.perception.plane import Plane, fit_plane_ransac, plane_height, refit_plane

__all__ = [
    "Candidate",
    "GeometricSegmenter",
    "OracleSegmenter",
    "SegmentationConfig",
    "depth_discontinuities",
]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class Candidate:
    """One candidate instance (an element of Z̃(t), Eq. 4.8).

    Attributes:
        mask: the instance mask (with its bounding box b̃_i).
        label: segmenter-side identifier l̃_i (the ground-truth id for the oracle, the
            component index for the geometric segmenter).
    """

    mask: Mask
    label: int


@dataclass(frozen=True)
class SegmentationConfig:
    """Parameters of :class:`GeometricSegmenter`.

    Attributes:
        min_depth, max_depth: valid depth range, metres.
        plane_threshold: RANSAC inlier distance, metres.
        plane_iterations: RANSAC hypotheses.
        plane_samples: points the plane fit uses (random subset of a strided grid).
        plane_stride: grid stride in pixels; None picks ``max(1, W // 160)``.
        min_height: foreground pixels rise above the plane by more than this, metres.
        max_height: and by less than this, metres (drops clutter far above the table).
        jump_min: depth-discontinuity threshold floor, metres.
        jump_footprints: the threshold also scales with the pixel footprint ``z / fx``: it is
            ``max(jump_min, jump_footprints * z / fx)``, so oblique surfaces are not cut.
        min_area: minimum component area, pixels.
        plane: a known support plane; when given, RANSAC is skipped.
        track_plane: reuse the previous frame's plane while its inlier fraction on this frame's
            sample stays at least ``track_tolerance`` times the fraction it was fitted with.
        track_tolerance: see ``track_plane``, in (0, 1].
    """

    min_depth: float = 0.1
    max_depth: float = 5.0
    plane_threshold: float = 0.01
    plane_iterations: int = 100
    plane_samples: int = 2000
    plane_stride: int | None = None
    min_height: float = 0.01
    max_height: float = 1.0
    jump_min: float = 0.02
    jump_footprints: float = 6.0
    min_area: int = 150
    plane: Plane | None = None
    track_plane: bool = True
    track_tolerance: float = 0.9

    def __post_init__(self) -> None:
        if not 0 <= self.min_depth < self.max_depth:
            raise ValueError(f"depth range [{self.min_depth}, {self.max_depth}] m is empty or negative")
        for name in ("plane_threshold", "jump_min", "min_height"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} is {getattr(self, name)}, expected > 0 metres")
        if self.max_height <= self.min_height:
            raise ValueError(f"max_height {self.max_height} must exceed min_height {self.min_height}")
        if self.plane_iterations < 1 or self.plane_samples < 3 or self.min_area < 1:
            raise ValueError("plane_iterations >= 1, plane_samples >= 3 and min_area >= 1 are required")
        if self.plane_stride is not None and self.plane_stride < 1:
            raise ValueError(f"plane_stride is {self.plane_stride}, expected >= 1 or None")
        if not 0 < self.track_tolerance <= 1:
            raise ValueError(f"track_tolerance is {self.track_tolerance}, expected in (0, 1]")


def depth_discontinuities(depth: np.ndarray, threshold: np.ndarray | float) -> np.ndarray:
    """Pixels on the far side of a depth jump between 4-neighbours.

    Only the farther pixel of a jump is marked, so an occluding object keeps its full silhouette
    and the occluded one loses a one-pixel rim along the occlusion boundary.

    Args:
        depth: (H, W) float32 metres.
        threshold: scalar or (H, W) jump threshold, metres.

    Returns:
        (H, W) bool.
    """
    cut = np.zeros(depth.shape, dtype=bool)
    thr = np.broadcast_to(np.asarray(threshold, dtype=np.float32), depth.shape)
    dx = depth[:, 1:] - depth[:, :-1]
    jump = np.abs(dx) > np.minimum(thr[:, 1:], thr[:, :-1])
    cut[:, 1:] |= jump & (dx > 0)
    cut[:, :-1] |= jump & (dx < 0)
    dy = depth[1:, :] - depth[:-1, :]
    jump = np.abs(dy) > np.minimum(thr[1:, :], thr[:-1, :])
    cut[1:, :] |= jump & (dy > 0)
    cut[:-1, :] |= jump & (dy < 0)
    return cut


class GeometricSegmenter:
    """Support plane + connected components (module docstring).

    Args:
        config: parameters.
        rng: generator for the RANSAC samples (the segmenter owns it: runs are reproducible).

    Attributes:
        last_plane: the support plane of the last frame (None before the first or if no plane
            could be fitted).
    """

    def __init__(self, config: SegmentationConfig | None = None, rng: np.random.Generator | int = 0) -> None:
        self.config = config or SegmentationConfig()
        self.rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
        self.last_plane: Plane | None = None

    def fit_plane(self, frame: RGBDFrame) -> Plane | None:
        """The support plane of ``frame`` (``config.plane`` if given); None with too few valid points."""
        cfg = self.config
        if cfg.plane is not None:
            return cfg.plane
        stride = cfg.plane_stride or max(1, frame.width // 160)
        sub = frame.depth[::stride, ::stride]
        vs, us = np.nonzero((sub > cfg.min_depth) & (sub < cfg.max_depth))
        if vs.size < 3:
            return None
        if vs.size > cfg.plane_samples:
            pick = self.rng.choice(vs.size, size=cfg.plane_samples, replace=False)
            vs, us = vs[pick], us[pick]
        pts = backproject(us * stride, vs * stride, sub[vs, us], frame.K)
        prev = self.last_plane if cfg.track_plane else None
        if prev is not None:
            inliers = np.abs(pts @ prev.normal + prev.offset) < cfg.plane_threshold
            if inliers.sum() >= 3 and inliers.mean() >= cfg.track_tolerance * prev.inlier_fraction:
                n, d = refit_plane(pts[inliers])
                return Plane(n, d, prev.inlier_fraction, int(pts.shape[0]))
        return fit_plane_ransac(pts, cfg.plane_threshold, self.rng, iterations=cfg.plane_iterations)

    def _support(self, frame: RGBDFrame) -> np.ndarray:
        """(H, W) bool: valid pixels between ``min_height`` and ``max_height`` above the plane."""
        cfg = self.config
        depth = frame.depth
        plane = self.fit_plane(frame)
        self.last_plane = plane
        if plane is None:
            logger.debug("frame at t=%.3f s: too few valid depth pixels for a support plane", frame.timestamp)
            return np.zeros(depth.shape, dtype=bool)
        height = plane_height(depth, frame.K, plane)
        return (
            (depth > cfg.min_depth)
            & (depth < cfg.max_depth)
            & (height > cfg.min_height)
            & (height < cfg.max_height)
        )

    def _pieces(self, frame: RGBDFrame, min_area: int) -> list[tuple[int, int, np.ndarray]]:
        """Foreground pieces ``(x0, y0, crop)``: components of the support cut at depth jumps.

        Components smaller than ``min_area`` pixels are skipped before cutting.
        """
        cfg = self.config
        above = self._support(frame)
        _, labels = cv2.connectedComponents(above.view(np.uint8), connectivity=4, ltype=cv2.CV_32S)
        H, W = above.shape
        scale = np.float32(cfg.jump_footprints / frame.K[0, 0])
        pieces = []
        for k, sl in enumerate(ndimage.find_objects(labels), start=1):
            if sl is None:
                continue
            # one pixel of context around the component: jumps to its neighbours are seen
            y0, y1 = max(sl[0].start - 1, 0), min(sl[0].stop + 1, H)
            x0, x1 = max(sl[1].start - 1, 0), min(sl[1].stop + 1, W)
            comp = labels[y0:y1, x0:x1] == k
            if np.count_nonzero(comp) < min_area:
                continue
            d = frame.depth[y0:y1, x0:x1]
            comp &= ~depth_discontinuities(d, np.maximum(np.float32(cfg.jump_min), d * scale))
            _, sub = cv2.connectedComponents(comp.view(np.uint8), connectivity=4, ltype=cv2.CV_32S)
            for j, ssl in enumerate(ndimage.find_objects(sub), start=1):
                if ssl is not None:
                    pieces.append((x0 + ssl[1].start, y0 + ssl[0].start, sub[ssl] == j))
        return pieces

    def foreground(self, frame: RGBDFrame) -> np.ndarray:
        """(H, W) bool: valid pixels above the support plane, cut at depth discontinuities."""
        out = np.zeros(frame.shape, dtype=bool)
        for x0, y0, crop in self._pieces(frame, 1):
            h, w = crop.shape
            out[y0 : y0 + h, x0 : x0 + w] |= crop
        return out

    def __call__(self, frame: RGBDFrame) -> list[Candidate]:
        """Candidates of ``frame`` in raster order of their first pixel, labelled 1, 2, ... in that order."""
        kept = []
        for x0, y0, crop in self._pieces(frame, self.config.min_area):
            area = int(np.count_nonzero(crop))
            if area >= self.config.min_area:
                first = int(np.argmax(crop[0]))  # the top row of a tight crop is never empty
                kept.append(
                    (
                        (y0, x0 + first),
                        Mask((x0, y0, x0 + crop.shape[1], y0 + crop.shape[0]), crop, frame.shape, area),
                    )
                )
        kept.sort(key=lambda item: item[0])
        return [Candidate(mask, k) for k, (_, mask) in enumerate(kept, start=1)]


class OracleSegmenter:
    """Ground-truth segmentation from ``frame.labels`` (or a label image given per call).

    Args:
        background_ids: ids that are not objects (0 by convention; add e.g. the table's id).
        min_area: drop instances smaller than this many pixels.
    """

    def __init__(self, background_ids: Sequence[int] = (0,), min_area: int = 1) -> None:
        if min_area < 1:
            raise ValueError(f"min_area is {min_area}, expected >= 1 pixel")
        self.background_ids = frozenset(int(i) for i in background_ids)
        self.min_area = int(min_area)

    def __call__(self, frame: RGBDFrame, labels: np.ndarray | None = None) -> list[Candidate]:
        """Candidates in increasing id order.

        Raises:
            ValueError: no label image (``frame.labels`` is None and none is given), or one of
                the wrong shape or with negative ids.
        """
        labels = frame.labels if labels is None else np.asarray(labels)
        if labels is None:
            raise ValueError(
                "OracleSegmenter needs frame.labels (a ground-truth id image); the frame has none"
            )
        if labels.shape != frame.shape:
            raise ValueError(f"labels has shape {labels.shape}, expected {frame.shape}")
        if labels.size and labels.min() < 0:
            raise ValueError(
                f"labels has negative ids (min {labels.min()}); shift ids so that 0 is background"
            )
        out = []
        for index, sl in enumerate(ndimage.find_objects(labels), start=1):
            if sl is None or index in self.background_ids:
                continue
            crop = labels[sl] == index
            area = int(crop.sum())
            if area < self.min_area:
                continue
            ys, xs = sl
            out.append(
                Candidate(Mask((xs.start, ys.start, xs.stop, ys.stop), crop, frame.shape, area), index)
            )
        return out
