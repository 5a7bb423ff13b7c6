"""The topological relation of two object masks (Eq. 4.22), tolerant of depth holes.

The relation is the first that holds of:

- ``contained``: one mask lies (>= ``contain_fraction``) inside the other's pixels, or inside
  the other's filled convex hull while not lying behind it (an object in a bowl); ``container``
  names the outer object;
- ``overlapping``: the masks share pixels, or they are adjacent and the nearer one (by more
  than the sensor's noise) covers at least ``overlap_fraction`` of the farther one's convex hull:
  a partial occlusion. The hull of a non-convex mask (two objects merged into one, a chair)
  covers much that is not the object, so the hull alone never makes two masks overlap: the
  nearer object must also be adjacent and in front;
- ``touching``: the masks are adjacent and the closest surface points across the boundary are
  within ``touch_gap`` metres in 3-D (adjacent in the image but apart in depth is not touching);
- ``disjoint`` otherwise.

*Adjacent* means within ``touch_px`` pixels (at 640 columns, scaled with the width), and a
band of invalid depth up to ``hole_px`` pixels wide between two masks does not separate them:
real sensors lose depth at object boundaries, so two touching objects are often a few pixels
of holes apart. Across such a band the gap cannot be measured: the masks touch when their
boundary bands lie at the same depth (within ``touch_gap``).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree

from pal.perception.frames import RGBDFrame, backproject
from pal.perception.masks import Mask, intersection_area
from pal.perception.quantiles import median

__all__ = ["TOPOLOGY", "TopologyConfig", "mask_hull", "topology"]

TOPOLOGY: tuple[str, ...] = ("disjoint", "touching", "overlapping", "contained")


@dataclass(frozen=True)
class TopologyConfig:
    """Thresholds of :func:`topology` (module docstring).

    Attributes:
        touch_px: adjacency distance, pixels at 640 columns.
        hole_px: width of an invalid-depth band that does not separate two masks, pixels at
            640 columns.
        touch_gap: largest 3-D gap between touching surfaces, metres.
        contain_fraction: fraction of a mask inside the other for containment.
        overlap_fraction: fraction of the farther mask's hull an occluder must cover.
        occlusion_gap: the nearer object is in front by more than this, metres.
    """

    touch_px: int = 3
    hole_px: int = 8
    touch_gap: float = 0.015
    contain_fraction: float = 0.95
    overlap_fraction: float = 0.05
    occlusion_gap: float = 0.03

    def __post_init__(self) -> None:
        if self.touch_px < 1 or self.hole_px < 0 or not self.touch_gap > 0 or not self.occlusion_gap > 0:
            raise ValueError(
                f"touch_px >= 1, hole_px >= 0, touch_gap > 0 and occlusion_gap > 0 are required; got {self}"
            )
        if not 0 < self.overlap_fraction < self.contain_fraction <= 1:
            raise ValueError(f"need 0 < overlap_fraction < contain_fraction <= 1; got {self}")


def mask_hull(mask: Mask) -> np.ndarray | None:
    """(P, 1, 2) int32 convex hull of a mask in image pixels (from its outer contours), or None."""
    contours, _ = cv2.findContours(mask.crop.view(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    if not contours:
        return None
    hull = cv2.convexHull(np.concatenate(contours))
    return hull + np.array([mask.bbox[0], mask.bbox[1]], np.int32)


def _hull_fill(hull: np.ndarray | None, x0: int, y0: int, shape: tuple[int, int]) -> np.ndarray:
    out = np.zeros(shape, dtype=np.uint8)
    if hull is not None:
        cv2.fillConvexPoly(out, hull - np.array([x0, y0], np.int32), 1)
    return out.view(bool)


def _disk(r: int) -> np.ndarray:
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))


def _reach(m: np.ndarray, invalid: np.ndarray, r: int, hole: int) -> np.ndarray:
    """Pixels within ``r`` of ``m``, also across invalid-depth bands up to ``hole`` wide."""
    grown = cv2.dilate(m.view(np.uint8), _disk(r)).view(bool)
    if hole > 0:
        holes = invalid & cv2.dilate(grown.view(np.uint8), _disk(hole)).view(bool)
        grown = cv2.dilate((grown | holes).view(np.uint8), _disk(r)).view(bool)
    return grown


def _points(frame: RGBDFrame, sel: np.ndarray, x0: int, y0: int, limit: int = 300) -> np.ndarray:
    depth = frame.depth[y0 : y0 + sel.shape[0], x0 : x0 + sel.shape[1]]
    vs, us = np.nonzero(sel & (depth > 0))
    if vs.size > limit:
        keep = np.linspace(0, vs.size - 1, limit).astype(np.int64)
        vs, us = vs[keep], us[keep]
    return backproject(us + x0, vs + y0, depth[vs, us], frame.K)


def _near(
    own: np.ndarray,
    other: np.ndarray,
    other_box: tuple[int, int, int, int],
    origin: tuple[int, int],
    invalid: np.ndarray,
    r: int,
    hole: int,
) -> np.ndarray:
    """``own & _reach(other, ...)`` on a region, computed only near the other mask's box.

    Nothing farther than ``2 r + hole`` from ``other`` can be reached, so the dilations run on
    the other's box grown by that much (the pair's region can be far larger).
    """
    pad = 2 * r + hole + 1
    h, w = own.shape
    bx0, by0, bx1, by1 = other_box
    wx0, wy0 = max(0, bx0 - origin[0] - pad), max(0, by0 - origin[1] - pad)
    wx1, wy1 = min(w, bx1 - origin[0] + pad), min(h, by1 - origin[1] + pad)
    out = np.zeros(own.shape, dtype=bool)
    if wx1 <= wx0 or wy1 <= wy0:
        return out
    win = np.s_[wy0:wy1, wx0:wx1]
    reach = _reach(np.ascontiguousarray(other[win]), np.ascontiguousarray(invalid[win]), r, hole)
    out[win] = own[win] & reach
    return out


def topology(
    frame: RGBDFrame,
    a: Mask,
    b: Mask,
    config: TopologyConfig | None = None,
    ids: tuple[int, int] = (0, 1),
    hulls: tuple[np.ndarray | None, np.ndarray | None] | None = None,
) -> tuple[str, int | None]:
    """Topological relation of two masks: (label in :data:`TOPOLOGY`, container id or None).

    Args:
        frame: the frame (depth).
        a: first mask.
        b: second mask.
        config: thresholds.
        ids: the objects' ids (the container is named by its id).
        hulls: the masks' :func:`mask_hull` when already computed.
    """
    cfg = config or TopologyConfig()
    ha, hb = hulls if hulls is not None else (mask_hull(a), mask_hull(b))
    inter = intersection_area(a, b)
    small, big = (a, b) if a.area <= b.area else (b, a)
    big_id = ids[1] if big is b else ids[0]
    if inter >= cfg.contain_fraction * small.area:
        return "contained", big_id
    scale = frame.width / 640.0
    r, hole = max(1, round(cfg.touch_px * scale)), round(cfg.hole_px * scale)
    m = r + hole
    ax0, ay0, ax1, ay1 = a.bbox
    bx0, by0, bx1, by1 = b.bbox
    hull_overlap = not (ax0 >= bx1 or bx0 >= ax1 or ay0 >= by1 or by0 >= ay1)
    if not hull_overlap and (ax0 >= bx1 + m or bx0 >= ax1 + m or ay0 >= by1 + m or by0 >= ay1 + m):
        return "disjoint", None  # boxes (and so masks and hulls) too far apart to meet
    x0, y0 = max(0, min(ax0, bx0) - m), max(0, min(ay0, by0) - m)
    x1, y1 = min(frame.width, max(ax1, bx1) + m), min(frame.height, max(ay1, by1) + m)
    ra, rb = a.region(x0, y0, x1, y1), b.region(x0, y0, x1, y1)
    depth = frame.depth[y0:y1, x0:x1]
    za, zb = depth[ra & (depth > 0)], depth[rb & (depth > 0)]
    shape = ra.shape
    if hull_overlap and za.size and zb.size:
        for inner, hull, z_in, z_out, oid in ((ra, hb, za, zb, ids[1]), (rb, ha, zb, za, ids[0])):
            inside = np.count_nonzero(inner & _hull_fill(hull, x0, y0, shape)) / max(
                np.count_nonzero(inner), 1
            )
            if inside >= cfg.contain_fraction and np.median(z_in) <= z_out.max() + cfg.touch_gap:
                return "contained", oid
    if inter > 0:
        return "overlapping", None
    invalid = depth <= 0
    near_a = _near(ra, rb, b.bbox, (x0, y0), invalid, r, hole)
    near_b = _near(rb, ra, a.bbox, (x0, y0), invalid, r, hole)
    if not near_a.any() or not near_b.any():
        return "disjoint", None
    pa, pb = _points(frame, near_a, x0, y0), _points(frame, near_b, x0, y0)
    if len(pa) == 0 or len(pb) == 0:
        return "disjoint", None
    da, db = float(median(pa[:, 2])), float(median(pb[:, 2]))
    if abs(da - db) > cfg.occlusion_gap:
        near, far, far_hull = (ra, rb, hb) if da < db else (rb, ra, ha)
        hull = _hull_fill(far_hull, x0, y0, shape)
        covered = np.count_nonzero(near & hull) / max(
            np.count_nonzero(hull & ~far) + np.count_nonzero(far), 1
        )
        if covered >= cfg.overlap_fraction:
            return "overlapping", None
    gap = float(cKDTree(pa).query(pb, k=1)[0].min())
    if gap <= cfg.touch_gap:
        return "touching", None
    direct = ra & cv2.dilate(rb.view(np.uint8), _disk(r)).view(bool)
    if not direct.any() and abs(da - db) <= cfg.touch_gap:
        return "touching", None  # only missing depth between them, at the same depth on both sides
    return "disjoint", None
