"""Segmentation Σ (Eq. 4.8): candidate object instances [l̃_i, b̃_i, m̃_i] from one RGB-D frame.

Two segmenters share the interface ``segmenter(frame) -> list[Candidate]``:

- :class:`GeometricSegmenter` (default, no learned weights): fit the support plane by RANSAC
  on a subsampled back-projection, keep valid pixels that rise more than ``min_height`` above
  it, cut the foreground at depth discontinuities, label 4-connected components and drop
  those below ``min_area`` pixels.
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
from pal.perception.plane import Plane, fit_plane_ransac, plane_height

__all__ = ["Candidate", "GeometricSegmenter", "OracleSegmenter", "SegmentationConfig", "depth_discontinuities"]

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
        return fit_plane_ransac(pts, cfg.plane_threshold, self.rng, iterations=cfg.plane_iterations)

    def foreground(self, frame: RGBDFrame) -> np.ndarray:
        """(H, W) bool: valid pixels above the support plane, cut at depth discontinuities."""
        cfg = self.config
        depth = frame.depth
        valid = (depth > cfg.min_depth) & (depth < cfg.max_depth)
        plane = self.fit_plane(frame)
        self.last_plane = plane
        if plane is None:
            logger.debug("frame at t=%.3f s: too few valid depth pixels for a support plane", frame.timestamp)
            return np.zeros(depth.shape, dtype=bool)
        height = plane_height(depth, frame.K, plane)
        fg = valid & (height > cfg.min_height) & (height < cfg.max_height)
        thr = np.maximum(np.float32(cfg.jump_min), depth * np.float32(cfg.jump_footprints / frame.K[0, 0]))
        return fg & ~depth_discontinuities(depth, thr)

    def __call__(self, frame: RGBDFrame) -> list[Candidate]:
        """Candidates of ``frame``, in raster order of their first pixel."""
        fg = self.foreground(frame)
        n, labels, stats, _ = cv2.connectedComponentsWithStats(fg.view(np.uint8), connectivity=4, ltype=cv2.CV_32S)
        out = []
        for k in range(1, n):
            x, y, w, h, area = (int(v) for v in stats[k])
            if area < self.config.min_area:
                continue
            crop = labels[y : y + h, x : x + w] == k
            out.append(Candidate(Mask((x, y, x + w, y + h), crop, frame.shape, area), k))
        return out


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
            raise ValueError("OracleSegmenter needs frame.labels (a ground-truth id image); the frame has none")
        if labels.shape != frame.shape:
            raise ValueError(f"labels has shape {labels.shape}, expected {frame.shape}")
        if labels.size and labels.min() < 0:
            raise ValueError(f"labels has negative ids (min {labels.min()}); shift ids so that 0 is background")
        out = []
        for index, sl in enumerate(ndimage.find_objects(labels), start=1):
            if sl is None or index in self.background_ids:
                continue
            crop = labels[sl] == index
            area = int(crop.sum())
            if area < self.min_area:
                continue
            ys, xs = sl
            out.append(Candidate(Mask((xs.start, ys.start, xs.stop, ys.stop), crop, frame.shape, area), index))
        return out
