"""Segmentation Σ (Eq. 4.8): candidate object instances [l̃_i, b̃_i, m̃_i] from one RGB-D frame.

Two segmenters share the interface ``segmenter(frame) -> list[Candidate]``:

- :class:`GeometricSegmenter` (default, no learned weights):

  1. the valid depth is sampled on a regular pixel grid and the **support plane** chosen by a
     prior (:mod:`pal.perception.support`): among the dominant planes (adaptive RANSAC with a
     seeded generator), the one the most points rest on, within a tilt of the up direction;
     large planes roughly perpendicular to it (walls) are *structure*;
  2. **thresholds follow the sensor's noise model** (:mod:`pal.perception.noise`):
     foreground pixels rise above the support by more than ``max(min_height, height_sigmas *
     sigma_z(z))`` and less than ``max_height``, and lie off every structure plane;
  3. invalid-depth gaps of up to ``hole_radius`` pixels between foreground pixels are
     **bridged** (:func:`~pal.perception.regions.bridge_invalid`), then 4-connected components
     are labelled;
  4. each component is **cut** where touching objects meet: at depth discontinuities
     (``max(jump_min, jump_footprints * z / fx, jump_sigmas * sigma_z)``), at **concave
     creases** of the surface (``crease_tau``, :mod:`pal.perception.creases`: one object's
     faces meet at convex edges, two touching objects at a concave one) and, with
     ``split_colour``, at colour edges backed by depth evidence: pixels with a weak step or a
     crease behind them (:func:`~pal.perception.regions.colour_depth_edges`), and colour edge
     curves that touch a concave crease nearer than ``colour_range`` and follow no convex edge
     (:func:`~pal.perception.regions.supported_colour_edges`: between the coplanar tops of
     touching objects); print on one object touches no such crease. Crease and colour-curve
     cuts are widened by ``cut_width`` metres (at most 3 pixels) so that a gap in them does
     not join two objects; the cut pixels go back to the piece next to them;
  5. pieces below the size rule join the neighbour they share the longest **smooth** border
     with (no depth discontinuity across it: texture slivers go back, a small object behind a
     step stays apart); enclosed holes of invalid depth are **filled**, and pieces are kept
     when their visible surface is at least ``min_size`` m² (``grounded_size`` for a piece
     that **stands on the support**: some of its pixels lie within ``ground_height`` of it,
     e.g. a tuna can or scissors, and it covers ``grounded_pixels``) and ``min_extent`` m
     across (**metric size**; ``min_area`` pixels only drops specks).

  With ``track_plane`` the previous frame's planes are kept, refined by least squares, while
  they explain the sampled points as well as when chosen (searched again when the view changes).
- :class:`OracleSegmenter`: one candidate per ground-truth id in ``frame.labels`` (e.g.
  MuJoCo segmentation), for ablations and evaluation.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage

from pal.checks import check_float, check_int
from pal.perception.creases import creases, surface_normals
from pal.perception.frames import RGBDFrame, backproject
from pal.perception.masks import Mask
from pal.perception.noise import DepthNoise
from pal.perception.plane import Plane, plane_height, refit_plane
from pal.perception.quantiles import median, quantiles
from pal.perception.regions import (
    bridge_invalid,
    colour_depth_edges,
    depth_discontinuities,
    fill_invalid_holes,
    merge_small,
    metric_areas,
    smooth_pairs,
    supported_colour_edges,
)
from pal.perception.support import SupportChoice, SupportConfig, choose_support

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
        mask: the instance mask (with its bounding box b̃_i); it may include pixels without
            depth (filled holes).
        label: segmenter-side identifier l̃_i (the ground-truth id for the oracle, the
            component index for the geometric segmenter).
        size: visible surface area, m² (0 when unknown, e.g. from the oracle).
    """

    mask: Mask
    label: int
    size: float = 0.0


@dataclass(frozen=True)
class SegmentationConfig:
    """Parameters of :class:`GeometricSegmenter` (module docstring).

    Attributes:
        min_depth, max_depth: valid depth range, metres.
        noise: the depth sensor's noise model.
        plane_threshold: plane inlier distance floor, metres ...
        plane_sigmas: ... or this many noise sigmas when larger.
        plane_iterations: the most RANSAC hypotheses per plane (adaptive below that).
        plane_stride: sampling grid step, pixels; None picks ``max(1, W // 80)``.
        support: how the support plane is chosen (prior, gravity hint, structure planes).
        min_height: foreground rises above the support by more than this floor, metres ...
        height_sigmas: ... or this many noise sigmas when larger.
        max_height: and by less than this, metres.
        jump_min: depth-discontinuity threshold floor, metres.
        jump_footprints: the threshold also scales with the pixel footprint ``z / fx``, so
            oblique surfaces are not cut ...
        jump_sigmas: ... and with the noise, this many sigmas.
        hole_radius: invalid gaps bridged between foreground pixels, pixels; None picks
            ``max(1, round(3 W / 640))``.
        split_colour: also cut at colour edges backed by depth evidence.
        crease_tau: cut at concave creases sharper than this (``-c`` of
            :mod:`pal.perception.creases`; 0.3 is about 17 degrees), 0 for none ...
        crease_sigmas: ... and deeper than this many depth-noise sigmas.
        colour_reach: a colour edge curve touches a crease within this many pixels (at 640
            columns), 0: no colour edge curves.
        colour_range: only creases nearer than this back colour edge curves, metres (farther,
            a crease is measured over several centimetres and is too coarse; on a real desk at
            1-1.5 m such curves cut the objects into pieces that change from frame to frame).
        normal_window: depth smoothing before the normals, grid pixels at 640 columns.
        normal_step: normals and creases from points this many pixels apart (at 640 columns).
        crease_pixels: creases are found on every s-th pixel, at most this many of the foreground.
        cut_width: crease and colour-curve cuts are widened by this many metres (<= 3 pixels).
        min_size: smallest visible surface kept, m².
        grounded_size: smallest visible surface kept for a piece standing on the support, m².
        ground_height: a piece stands on the support when at least 3 of its pixels lie lower
            than this above it, metres.
        grounded_pixels: ... and ``grounded_size`` applies only to a piece of at least this
            many pixels (at 640 columns): fewer, a far piece is too coarse to describe or track.
        min_extent: smallest 3-D extent kept (largest side of the points' box), metres.
        min_area: pieces below this many pixels are specks, dropped before anything else.
        range_fraction: pieces whose median depth exceeds this fraction of ``max_depth`` are
            dropped: they are fragments of what lies beyond the range (far walls cut by it).
        plane: a known support plane; when given, the planes are not searched.
        track_plane: reuse the previous frame's planes while the support's inlier fraction on
            this frame's sample stays at least ``track_tolerance`` times its fitted fraction.
        track_tolerance: see ``track_plane``, in (0, 1].
    """

    min_depth: float = 0.1
    max_depth: float = 6.0
    noise: DepthNoise = DepthNoise()
    plane_threshold: float = 0.01
    plane_sigmas: float = 3.0
    plane_iterations: int = 500
    plane_stride: int | None = None
    support: SupportConfig = SupportConfig()
    min_height: float = 0.01
    height_sigmas: float = 3.0
    max_height: float = 1.5
    jump_min: float = 0.02
    jump_footprints: float = 6.0
    jump_sigmas: float = 5.0
    hole_radius: int | None = None
    split_colour: bool = True
    crease_tau: float = 0.3
    crease_sigmas: float = 4.0
    colour_reach: float = 3.0
    colour_range: float = 1.0
    normal_window: int = 5
    normal_step: int = 3
    crease_pixels: int = 80_000
    cut_width: float = 0.005
    min_size: float = 0.0025
    grounded_size: float = 0.001
    ground_height: float = 0.02
    grounded_pixels: int = 700
    min_extent: float = 0.03
    min_area: int = 20
    range_fraction: float = 0.9
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
        for name in (
            *("plane_sigmas", "height_sigmas", "jump_sigmas", "jump_footprints", "min_size", "min_extent"),
            *("crease_sigmas", "colour_reach", "colour_range", "cut_width", "grounded_size", "ground_height"),
        ):
            check_float(name, getattr(self, name), 0.0)
        check_float("crease_tau", self.crease_tau, 0.0, 2.0, open_high=True)
        check_int("normal_window", self.normal_window)
        check_int("normal_step", self.normal_step)
        check_int("crease_pixels", self.crease_pixels)
        check_int("plane_iterations", self.plane_iterations)
        check_int("min_area", self.min_area)
        check_int("grounded_pixels", self.grounded_pixels, minimum=0)
        check_float("range_fraction", self.range_fraction, 0.0, 1.0, open_low=True)
        if self.plane_stride is not None:
            check_int("plane_stride", self.plane_stride)
        if self.hole_radius is not None:
            check_int("hole_radius", self.hole_radius, minimum=0)
        if not 0 < self.track_tolerance <= 1:
            raise ValueError(f"track_tolerance is {self.track_tolerance}, expected in (0, 1]")


class GeometricSegmenter:
    """Support plane + connected components, cut at depth and colour edges (module docstring).

    Args:
        config: parameters.
        rng: generator for the RANSAC samples (the segmenter owns it: runs are reproducible).

    Attributes:
        last_plane: the support plane of the last frame (None before the first or if no plane
            could be fitted).
        last_choice: the planes of the last search (support, structure, candidates, scores),
            or None while tracked planes are reused.
    """

    def __init__(self, config: SegmentationConfig | None = None, rng: np.random.Generator | int = 0) -> None:
        self.config = config or SegmentationConfig()
        self.rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
        self.last_plane: Plane | None = None
        self.last_structure: tuple[tuple[Plane, np.ndarray], ...] = ()
        self.last_choice: SupportChoice | None = None
        self._stride = 1

    def _sample(self, frame: RGBDFrame) -> tuple[np.ndarray, np.ndarray, tuple[int, int], np.ndarray]:
        """Valid depth on the sampling grid: (points (N, 3), cells (N, 2), grid shape, thresholds (N,))."""
        cfg = self.config
        stride = cfg.plane_stride or max(1, frame.width // 80)
        self._stride = stride
        sub = frame.depth[::stride, ::stride]
        vs, us = np.nonzero((sub > cfg.min_depth) & (sub < cfg.max_depth))
        z = sub[vs, us]
        pts = backproject(us * stride, vs * stride, z, frame.K)
        thr = cfg.noise.threshold(z, cfg.plane_sigmas, cfg.plane_threshold).astype(np.float64)
        return pts, np.stack([vs, us], axis=1), sub.shape, thr

    def fit_plane(self, frame: RGBDFrame) -> Plane | None:
        """The support plane of ``frame`` (``config.plane`` if given); None with too few valid points.

        Also sets :attr:`last_structure` (walls) and :attr:`last_choice`.
        """
        cfg = self.config
        if cfg.plane is not None:
            self.last_structure, self.last_choice = (), None
            return cfg.plane
        pts, cells, shape, thr = self._sample(frame)
        if pts.shape[0] < 3:
            self.last_structure, self.last_choice = (), None
            return None
        prev = self.last_plane if cfg.track_plane else None
        if prev is not None:
            inliers = np.abs(pts @ prev.normal + prev.offset) < thr
            if inliers.sum() >= 3 and inliers.mean() >= cfg.track_tolerance * prev.inlier_fraction:
                n, d = refit_plane(pts[inliers], 1.0 / thr[inliers] ** 2)
                self.last_choice = None
                return Plane(n, d, prev.inlier_fraction, int(pts.shape[0]))
        choice = choose_support(pts, cells, shape, thr, self.rng, cfg.support)
        self.last_choice = choice
        self.last_structure = tuple(zip(choice.structure, choice.structure_cells, strict=True))
        return choice.support

    def _foreground(self, frame: RGBDFrame) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(H, W) bool foreground (step 2 of the module docstring), float32 depth sigma and height, metres."""
        cfg = self.config
        depth = frame.depth
        plane = self.fit_plane(frame)
        self.last_plane = plane
        sigma = cfg.noise.sigma(depth)
        if plane is None:
            logger.debug("frame at t=%.3f s: too few valid depth pixels for a support plane", frame.timestamp)
            return np.zeros(depth.shape, dtype=bool), sigma, np.zeros_like(sigma)
        height = plane_height(depth, frame.K, plane)
        fg = (
            (depth > cfg.min_depth)
            & (depth < cfg.max_depth)
            & (height > np.maximum(np.float32(cfg.min_height), np.float32(cfg.height_sigmas) * sigma))
            & (height < cfg.max_height)
        )
        if self.last_structure:
            thr = np.maximum(np.float32(cfg.plane_threshold), np.float32(cfg.plane_sigmas) * sigma)
            s = self._stride
            for wall, cells in self.last_structure:
                region = cv2.dilate(cells.view(np.uint8), np.ones((3, 3), np.uint8))
                region = np.repeat(np.repeat(region, s, axis=0), s, axis=1)[
                    : depth.shape[0], : depth.shape[1]
                ]
                fg &= ~((np.abs(plane_height(depth, frame.K, wall)) < thr) & (region > 0))
        return fg, sigma, height

    def _pieces(self, frame: RGBDFrame, keep_small: bool) -> list[tuple[int, int, np.ndarray, float, float]]:
        """Foreground pieces ``(x0, y0, crop, size m², smallest size kept m²)`` (steps 3-5 of the module docstring).

        With ``keep_small`` every piece is returned, whatever its size.
        """
        cfg = self.config
        depth = frame.depth
        fg, sigma, height = self._foreground(frame)
        invalid = depth <= 0
        fx, fy = float(frame.K[0, 0]), float(frame.K[1, 1])
        jump = self._jump(fx)(depth, sigma)
        radius = cfg.hole_radius if cfg.hole_radius is not None else max(1, round(3 * frame.width / 640))
        fg = bridge_invalid(fg, depth, radius, self._jump(fx))
        cut = self._cuts(frame, fg, sigma, jump)
        r = 3
        n, labels = cv2.connectedComponents((fg & ~cut).view(np.uint8), connectivity=4, ltype=cv2.CV_32S)
        if n <= 1:
            return []
        # cut pixels join the piece next to them, then pieces below the size rule their smooth neighbour
        for _ in range(r + 2):
            grown = cv2.dilate(labels.astype(np.float32), np.ones((3, 3), np.uint8)).astype(np.int32)
            labels = np.where(fg & (labels == 0), grown, labels)
        sizes = metric_areas(labels, n, depth, fx, fy)
        low = fg & (height < cfg.ground_height)
        pixels = np.bincount(labels.ravel(), minlength=n) * (640.0 / frame.width) ** 2
        grounded = (np.bincount(labels[low], minlength=n) >= 3) & (pixels >= cfg.grounded_pixels)
        smallest = np.where(grounded, cfg.grounded_size, cfg.min_size)
        if not keep_small and not (sizes[1:] >= smallest[1:]).all():
            labels = merge_small(labels, sizes >= smallest, smooth_pairs(depth, jump))
            sizes = metric_areas(labels, n, depth, fx, fy)
        pieces = []
        for j, sl in enumerate(ndimage.find_objects(labels), start=1):
            if sl is None or (not keep_small and sizes[j] < smallest[j]):
                continue  # (a piece below its size rule is never a candidate)
            crop = fill_invalid_holes(labels[sl] == j, invalid[sl])
            pieces.append((sl[1].start, sl[0].start, crop, float(sizes[j]), float(smallest[j])))
        return pieces

    def _cuts(self, frame: RGBDFrame, fg: np.ndarray, sigma: np.ndarray, jump: np.ndarray) -> np.ndarray:
        """(H, W) bool cut pixels (step 4 of the module docstring): jumps, widened creases and colour edges."""
        cfg = self.config
        depth = frame.depth
        scale = frame.width / 640.0
        weak = np.zeros_like(fg)
        concave = convex = weak
        if cfg.crease_tau > 0:
            concave, convex = self._creases(frame, fg, jump)
            weak = concave.copy()
        if cfg.split_colour and cfg.colour_reach > 0:
            m = max(1, round(cfg.normal_step * scale)) + 2
            inner = cv2.erode(fg.view(np.uint8), np.ones((2 * m + 1, 2 * m + 1), np.uint8)).view(bool)
            reach = max(1, round(cfg.colour_reach * scale))
            near = fg & (depth < np.float32(cfg.colour_range))
            weak |= supported_colour_edges(frame.rgb, near & ~convex, concave & inner & near, reach)
        strong = depth_discontinuities(depth, jump) & fg
        if cfg.split_colour:
            strong |= colour_depth_edges(frame.gray(), depth, sigma, fg)
        # widen the crease and colour-curve cuts by cut_width metres: fx w / z pixels, at most 3
        # (depth cuts stay thin: widened, they would shatter thin things such as chair slats)
        radius = np.where(depth > 0, np.float32(cfg.cut_width * frame.K[0, 0]) / np.maximum(depth, 1e-6), 0.0)
        radius = np.rint(np.minimum(radius, 3.0)).astype(np.int8)
        cut = weak | strong
        for r in range(1, 4):
            sel = weak & (radius == r)
            if sel.any():
                disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
                cut |= cv2.dilate(sel.view(np.uint8), disk).view(bool)
        return cut & fg

    def _creases(self, frame: RGBDFrame, fg: np.ndarray, jump: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(H, W) bool concave and convex creases inside the foreground (its bounding box, every s-th pixel)."""
        cfg = self.config
        concave, convex = np.zeros(fg.shape, dtype=bool), np.zeros(fg.shape, dtype=bool)
        rows, cols = np.flatnonzero(fg.any(axis=1)), np.flatnonzero(fg.any(axis=0))
        if rows.size == 0:
            return concave, convex
        # every s-th pixel, s chosen so that at most crease_pixels of the foreground are used
        s = max(1, math.ceil(math.sqrt(np.count_nonzero(fg) / cfg.crease_pixels)))
        step = max(1, round(cfg.normal_step * frame.width / 640.0 / s))
        window = 2 * max(1, round(cfg.normal_window * frame.width / 640.0 / 2)) + 1
        m = s * (2 * step + window)
        y0, y1 = max(0, rows[0] - m), min(fg.shape[0], rows[-1] + m + 1)
        x0, x1 = max(0, cols[0] - m), min(fg.shape[1], cols[-1] + m + 1)
        K = frame.K.copy()
        K[0, 2] -= x0
        K[1, 2] -= y0
        K[:2] /= s
        depth = frame.depth[y0:y1:s, x0:x1:s]
        pts, normals = surface_normals(depth, K, window, step)
        sigma = cfg.noise.sigma(depth) * np.float32(cfg.crease_sigmas)
        cc, cv = creases(pts, normals, step, cfg.crease_tau, jump[y0:y1:s, x0:x1:s], sigma)
        for out, sub in ((concave, cc), (convex, cv)):
            out[y0:y1, x0:x1] = np.repeat(np.repeat(sub, s, 0), s, 1)[: y1 - y0, : x1 - x0] & fg[y0:y1, x0:x1]
        return concave, convex

    def _jump(self, fx: float) -> Callable[..., np.ndarray]:
        """The depth-discontinuity threshold (metres) as a function of depth (metres)."""
        cfg = self.config

        def jump(z: np.ndarray, sigma: np.ndarray | None = None) -> np.ndarray:
            footprint = z * np.float32(cfg.jump_footprints / fx)
            s = cfg.noise.sigma(z) if sigma is None else sigma
            return np.maximum(
                np.maximum(np.float32(cfg.jump_min), footprint), np.float32(cfg.jump_sigmas) * s
            )

        return jump

    def large_enough(
        self, frame: RGBDFrame, x0: int, y0: int, crop: np.ndarray, size: float, smallest: float
    ) -> bool:
        """A piece is kept: ``size`` m² >= ``smallest``, median depth in range, ``min_extent`` across."""
        cfg = self.config
        if int(np.count_nonzero(crop)) < cfg.min_area or size < smallest:
            return False
        h, w = crop.shape
        z = frame.depth[y0 : y0 + h, x0 : x0 + w]
        vs, us = np.nonzero(crop & (z > 0))
        if vs.size < 3:
            return False
        if float(median(z[vs, us])) > cfg.range_fraction * cfg.max_depth:
            return False
        if vs.size > 200:
            pick = np.linspace(0, vs.size - 1, 200).astype(np.int64)
            vs, us = vs[pick], us[pick]
        pts = backproject(us + x0, vs + y0, z[vs, us], frame.K)
        lo, hi = quantiles(pts, (2.0, 98.0))
        return float(np.max(hi - lo)) >= cfg.min_extent

    def foreground(self, frame: RGBDFrame) -> np.ndarray:
        """(H, W) bool: the pieces of the foreground, whatever their size (cuts removed, holes filled)."""
        out = np.zeros(frame.shape, dtype=bool)
        for x0, y0, crop, _, _ in self._pieces(frame, True):
            h, w = crop.shape
            out[y0 : y0 + h, x0 : x0 + w] |= crop
        return out

    def __call__(self, frame: RGBDFrame) -> list[Candidate]:
        """Candidates of ``frame`` in raster order of their first pixel, labelled 1, 2, ... in that order."""
        kept = []
        for x0, y0, crop, size, smallest in self._pieces(frame, False):
            if not self.large_enough(frame, x0, y0, crop, size, smallest):
                continue
            first = int(np.argmax(crop[0]))  # the top row of a tight crop is never empty
            area = int(np.count_nonzero(crop))
            mask = Mask((x0, y0, x0 + crop.shape[1], y0 + crop.shape[0]), crop, frame.shape, area)
            kept.append(((y0, x0 + first), mask, size))
        kept.sort(key=lambda item: item[0])
        return [Candidate(mask, k, size) for k, (_, mask, size) in enumerate(kept, start=1)]


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
