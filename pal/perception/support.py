"""Choosing the support plane by a prior: the dominant plane that supports the most objects.

The largest plane of a real RGB-D frame is often the floor or a wall, not the table the
objects stand on. The support is therefore chosen among the dominant planes of the frame
(:func:`pal.perception.plane.extract_planes`, thresholds from the sensor's noise model) by
what it supports:

- a plane's *surface* is the largest connected region of its inliers in the image (points
  sampled on a regular pixel grid), so that a plane through the tops of several objects at
  the same height (a keyboard, a book, a phone's base) is not taken for one surface;
- a point *rests on* a plane when it lies above it (higher than the inlier threshold, lower
  than ``max_object_height``), is not an inlier of any candidate plane, its foot on the plane
  falls inside the footprint of the plane's surface (the convex hull of the surface's points
  in the plane, on a grid of ``cell`` metres), and no other such plane lies between it and this
  one (the nearest support below it);
- the support is the candidate on which the most points rest. Ties and frames where nothing
  rests on any plane go to the largest plane.
- candidates whose surface's footprint (hull area) is below ``min_area`` are not
  supports: they are the tops of objects, e.g. a plane through the lids of touching short
  cans and boxes (unless no candidate is that large);
- only candidates whose normal is within ``max_tilt_deg`` of the up direction ``up`` (camera
  coordinates) are considered. By default ``up`` is the image's up direction ``(0, -1, 0)``
  with 60 degrees of tilt: a camera held upright or looking down at a table (walls are then
  about 90 degrees from up and never support). Give the true gravity direction or the expected
  normal when it is known (e.g. a camera looking straight down: ``(0, 0, -1)``), or None for no
  prior. When no candidate is within the tilt, every candidate is considered.

So a desk wins over the floor under it (the desk's objects rest on the desk, its legs on the
floor), and the floor wins in a room of furniture over a table with a few things on it.
Other large planes roughly perpendicular to the support (walls, cupboard fronts: the
footprint of their surface is larger than ``structure_area``) are *structure*: the segmenter
removes the pixels of their surface (not of the infinite plane, which would slice every object
it crosses) from the foreground.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from pal.checks import check_float, check_int
from pal.perception.plane import Plane, extract_planes

__all__ = ["SupportChoice", "SupportConfig", "choose_support", "plane_basis"]


@dataclass(frozen=True)
class SupportConfig:
    """How the support plane is chosen (module docstring).

    Attributes:
        max_planes: dominant planes considered.
        min_fraction: a candidate holds at least this fraction of the sampled points.
        max_object_height: points up to this height above a plane may rest on it, metres.
        cell: grid cell of a plane's footprint, metres.
        up: gravity or normal hint, the up direction (3,) in camera coordinates (x right, y
            down, z forward), or None for no prior (module docstring).
        max_tilt_deg: the largest angle between ``up`` and the support's normal, deg.
        structure_area: a non-support plane larger than this (footprint hull, m²) ...
        structure_angle_deg: ... and at least this far from parallel to the support, deg, is
            structure (a wall): its pixels are not foreground.
    """

    max_planes: int = 4
    min_fraction: float = 0.05
    max_object_height: float = 1.0
    cell: float = 0.05
    up: tuple[float, float, float] | None = (0.0, -1.0, 0.0)
    max_tilt_deg: float = 60.0
    structure_area: float = 1.5
    structure_angle_deg: float = 60.0
    min_area: float = 0.08

    def __post_init__(self) -> None:
        check_int("max_planes", self.max_planes)
        check_float("min_fraction", self.min_fraction, 0.0, 1.0, open_low=True)
        check_float("max_object_height", self.max_object_height, 0.0, open_low=True)
        check_float("cell", self.cell, 0.0, open_low=True)
        check_float("max_tilt_deg", self.max_tilt_deg, 0.0, 90.0, open_low=True)
        check_float("structure_area", self.structure_area, 0.0, open_low=True)
        check_float("structure_angle_deg", self.structure_angle_deg, 0.0, 90.0)
        check_float("min_area", self.min_area, 0.0)
        if self.up is not None:
            up = np.asarray(self.up, dtype=np.float64)
            if up.shape != (3,) or not np.all(np.isfinite(up)) or np.linalg.norm(up) < 1e-9:
                raise ValueError(f"up is {self.up!r}, expected a non-zero finite (3,) direction or None")
            object.__setattr__(self, "up", tuple(float(v) for v in up / np.linalg.norm(up)))


@dataclass(frozen=True, eq=False)
class SupportChoice:
    """The support plane of a frame and the other planes found.

    Attributes:
        support: the chosen plane, or None when no plane was found.
        structure: large planes roughly perpendicular to the support (walls).
        structure_cells: for each structure plane, (rows, cols) bool of the sampling grid: the
            cells of its surface.
        candidates: every dominant plane, largest first.
        scores: points resting on each candidate (-1: excluded by the hint).
    """

    support: Plane | None
    structure: tuple[Plane, ...]
    structure_cells: tuple[np.ndarray, ...]
    candidates: tuple[Plane, ...]
    scores: tuple[int, ...]


def plane_basis(normal: np.ndarray) -> np.ndarray:
    """(2, 3) orthonormal in-plane axes of a plane with unit ``normal``.

    The first axis is the camera's x axis projected on the plane (or z when x is normal to
    it), so plane coordinates read left to right as the image does.
    """
    n = np.asarray(normal, dtype=np.float64)
    ref = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    e1 = ref - (ref @ n) * n
    e1 /= np.linalg.norm(e1)
    return np.stack([e1, np.cross(n, e1)])


def _footprint(xy: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray, float]:
    """Convex-hull footprint of 2-D points on a grid: (filled uint8 grid, origin (2,), hull area m²)."""
    lo = xy.min(axis=0) - cell
    ij = np.floor((xy - lo) / cell).astype(np.int32)
    shape = ij.max(axis=0) + 2
    grid = np.zeros((int(shape[1]), int(shape[0])), np.uint8)
    hull = cv2.convexHull(np.unique(ij, axis=0).reshape(-1, 1, 2))
    cv2.fillConvexPoly(grid, hull, 1)
    return grid, lo, float(cv2.contourArea(hull)) * cell * cell


def _inside(grid: np.ndarray, lo: np.ndarray, cell: float, xy: np.ndarray) -> np.ndarray:
    ij = np.floor((xy - lo) / cell).astype(np.int64)
    ok = (ij[:, 0] >= 0) & (ij[:, 1] >= 0) & (ij[:, 0] < grid.shape[1]) & (ij[:, 1] < grid.shape[0])
    out = np.zeros(xy.shape[0], dtype=bool)
    out[ok] = grid[ij[ok, 1], ij[ok, 0]] > 0
    return out


def _distinct(
    pts: np.ndarray, threshold: np.ndarray, found: list[tuple[Plane, np.ndarray]]
) -> list[tuple[Plane, np.ndarray]]:
    """Drop slivers: a plane most of whose inliers lie near a larger, nearly parallel plane.

    Noisy or slightly curved surfaces (real depth sensors bend a desk by a centimetre or two)
    leave points just outside the inlier threshold of their plane; a later RANSAC round fits
    them with a slightly tilted copy. Such a copy (normals within 10 degrees, most inliers within
    3 cm or 3 thresholds of the larger plane) is part of that surface: its inliers join it.
    """
    kept: list[tuple[Plane, np.ndarray]] = []
    for plane, inl in found:
        for k, (big, big_inl) in enumerate(kept):
            if abs(float(plane.normal @ big.normal)) < math.cos(math.radians(10.0)):
                continue
            near = np.abs(pts[inl] @ big.normal + big.offset) < np.maximum(3.0 * threshold[inl], 0.03)
            if near.mean() > 0.5:
                kept[k] = (big, big_inl | inl)
                break
        else:
            kept.append((plane, inl))
    return kept


def _surface(cells: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(M,) bool: which of M grid cells (row, col) belong to their largest 8-connected region."""
    grid = np.zeros(shape, np.uint8)
    grid[cells[:, 0], cells[:, 1]] = 1
    n, labels, stats, _ = cv2.connectedComponentsWithStats(grid, connectivity=8)
    if n <= 1:
        return np.zeros(cells.shape[0], dtype=bool)
    biggest = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    return labels[cells[:, 0], cells[:, 1]] == biggest


def choose_support(
    points: np.ndarray,
    cells: np.ndarray,
    shape: tuple[int, int],
    threshold: np.ndarray,
    rng: np.random.Generator,
    config: SupportConfig,
) -> SupportChoice:
    """Choose the support plane of points sampled on a pixel grid (module docstring).

    Args:
        points: (N, 3) camera-frame points, metres (the frame's valid depth on a grid).
        cells: (N, 2) int (row, col) of each point on the sampling grid.
        shape: (rows, cols) of the sampling grid.
        threshold: (N,) plane inlier distance per point, metres (from the noise model).
        rng: source of the RANSAC samples.
        config: the prior's parameters.
    """
    pts = np.asarray(points, dtype=np.float64)
    cells = np.asarray(cells, dtype=np.int64)
    if pts.shape[0] < 3:
        return SupportChoice(None, (), (), (), ())
    found = extract_planes(
        pts, threshold, rng, max_planes=config.max_planes, min_fraction=config.min_fraction
    )
    found = _distinct(pts, threshold, found)
    if not found:
        return SupportChoice(None, (), (), (), ())
    planes = [p for p, _ in found]
    on_any = np.zeros(pts.shape[0], dtype=bool)
    for _, inl in found:
        on_any |= inl
    free = np.flatnonzero(~on_any)
    heights = np.full((len(found), free.size), np.inf)
    areas, surfaces = [], []
    for k, (plane, inl) in enumerate(found):
        basis = plane_basis(plane.normal)
        idx = np.flatnonzero(inl)
        surface = idx[_surface(cells[idx], shape)]
        grid, lo, area = _footprint(pts[surface] @ basis.T, config.cell)
        areas.append(area)
        surfaces.append(surface)
        h = pts[free] @ plane.normal + plane.offset
        rests = (h > threshold[free]) & (h < config.max_object_height)
        rests &= _inside(grid, lo, config.cell, pts[free] @ basis.T)
        heights[k, rests] = h[rests]
    allowed = list(range(len(found)))
    if config.up is not None:
        cos_tilt = math.cos(math.radians(config.max_tilt_deg))
        allowed = [
            k for k, p in enumerate(planes) if float(p.normal @ np.asarray(config.up)) >= cos_tilt
        ] or allowed
    if config.min_area > 0:
        allowed = [k for k in allowed if areas[k] >= config.min_area] or allowed
    sub = heights[allowed]
    nearest = np.argmin(sub, axis=0)
    resting = np.isfinite(sub.min(axis=0))
    counts = np.bincount(nearest[resting], minlength=len(allowed))
    scores = [-1] * len(found)
    for j, k in enumerate(allowed):
        scores[k] = int(counts[j])
    best = max(allowed, key=lambda k: (scores[k], int(found[k][1].sum())))
    support = planes[best]
    cos_wall = math.cos(math.radians(config.structure_angle_deg))
    walls = [
        k
        for k, p in enumerate(planes)
        if k != best
        and areas[k] >= config.structure_area
        and abs(float(p.normal @ support.normal)) <= cos_wall
    ]
    regions = []
    for k in walls:
        grid = np.zeros(shape, dtype=bool)
        grid[cells[surfaces[k], 0], cells[surfaces[k], 1]] = True
        regions.append(grid)
    return SupportChoice(
        support, tuple(planes[k] for k in walls), tuple(regions), tuple(planes), tuple(scores)
    )
