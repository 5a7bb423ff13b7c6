"""Visual quantization VQ (Eq. 4.19-4.20): the 54-dimensional appearance descriptor of a snapshot.

Layout (the proof of concept's table, poc-notes.md), per snapshot crop and mask:

====  ===========  =============================================================================
dims  family       feature
====  ===========  =============================================================================
0-5   geometry     area ratio in the crop, aspect ratio (w/h of the mask's box), extent (area /
                   box area), solidity (area / filled convex hull), compactness 4πA/P²,
                   eccentricity sqrt(1 - λ_min/λ_max) of the second central moments
6-12  hu           log-scaled Hu moments of the mask, -sign(h) log10(|h| + 1e-12)
13-44 hsv          HSV histogram over the mask: H in 8 bins over [0, 180), S in 4 bins over
                   [0, 256), row-major (H outer), L1-normalised
45    edges        Canny(50, 150) edge density: edge pixels in the mask / mask area
46-53 orientation  gradient-orientation histogram (Sobel 3x3), angle mod 180° in 8 bins,
                   magnitude-weighted, L1-normalised (all zeros on a uniform patch)
====  ===========  =============================================================================

The object-level descriptor (Eq. 4.20) is the mean over the gallery. The families have very
different scales (Hu moments are unbounded), so distances should be taken after
:class:`pal.perception.normalise.RobustNormaliser` with the histogram families scaled as a
whole: ``RobustNormaliser(VISUAL_FAMILIES, shared=VISUAL_HISTOGRAMS)``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import cv2
import numpy as np

__all__ = [
    "VISUAL_DIM",
    "VISUAL_FAMILIES",
    "VISUAL_HISTOGRAMS",
    "VISUAL_NAMES",
    "gallery_visual_descriptor",
    "visual_descriptor",
]

VISUAL_FAMILIES: dict[str, slice] = {
    "geometry": slice(0, 6),
    "hu": slice(6, 13),
    "hsv": slice(13, 45),
    "edges": slice(45, 46),
    "orientation": slice(46, 54),
}
VISUAL_DIM = 54
#: The families that are histograms (distributions over bins): normalise them as a whole,
#: ``RobustNormaliser(VISUAL_FAMILIES, shared=VISUAL_HISTOGRAMS)``.
VISUAL_HISTOGRAMS: tuple[str, ...] = ("hsv", "orientation")
VISUAL_NAMES: tuple[str, ...] = (
    "area_ratio",
    "aspect_ratio",
    "extent",
    "solidity",
    "compactness",
    "eccentricity",
    *(f"hu_{k}" for k in range(1, 8)),
    *(f"hsv_h{h}_s{s}" for h in range(8) for s in range(4)),
    "edge_density",
    *(f"grad_orient_{k}" for k in range(8)),
)


def _geometry(mask_u8: np.ndarray, area: int) -> np.ndarray:
    h, w = mask_u8.shape
    _, _, bw, bh = cv2.boundingRect(mask_u8)
    contours, _ = cv2.findContours(mask_u8, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    pts = np.concatenate(contours, axis=0)
    hull = cv2.convexHull(pts)
    filled = np.zeros_like(mask_u8)
    cv2.fillConvexPoly(filled, hull, 1)
    hull_area = max(int(filled.sum()), area)
    perimeter = sum(cv2.arcLength(c, True) for c in contours)
    compactness = 4.0 * math.pi * area / perimeter**2 if perimeter > 0 else 1.0
    m = cv2.moments(mask_u8, binaryImage=True)
    mu20, mu02, mu11 = m["mu20"] / m["m00"], m["mu02"] / m["m00"], m["mu11"] / m["m00"]
    common = math.sqrt(((mu20 - mu02) / 2.0) ** 2 + mu11**2)
    lam1, lam2 = (mu20 + mu02) / 2.0 + common, (mu20 + mu02) / 2.0 - common
    ecc = math.sqrt(max(0.0, 1.0 - lam2 / lam1)) if lam1 > 1e-12 else 0.0
    return np.array(
        [
            area / float(h * w),
            bw / float(bh),
            area / float(bw * bh),
            area / float(hull_area),
            compactness,
            ecc,
        ]
    )


def visual_descriptor(rgb: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """The 54-d descriptor of one snapshot (module docstring).

    Args:
        rgb: (h, w, 3) uint8 crop, RGB order.
        mask: (h, w) bool object mask in the crop.

    Returns:
        (54,) float64.

    Raises:
        ValueError: wrong shapes or dtypes, or an empty (zero-size) mask.
    """
    rgb = np.asarray(rgb)
    mask = np.asarray(mask, dtype=bool)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise ValueError(f"rgb has shape {rgb.shape} dtype {rgb.dtype}, expected (h, w, 3) uint8")
    if mask.shape != rgb.shape[:2]:
        raise ValueError(f"mask has shape {mask.shape}, expected {rgb.shape[:2]}")
    area = int(mask.sum())
    if area == 0:
        raise ValueError(
            f"mask of shape {mask.shape} is empty (zero-size); a visual descriptor needs >= 1 pixel"
        )
    rgb = np.ascontiguousarray(rgb)
    mask_u8 = mask.astype(np.uint8)
    geometry = _geometry(mask_u8, area)
    hu = cv2.HuMoments(cv2.moments(mask_u8, binaryImage=True)).ravel()
    hu = -np.sign(hu) * np.log10(np.abs(hu) + 1e-12)
    hsv = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV)
    hist = cv2.calcHist([hsv], [0, 1], mask_u8, [8, 4], [0, 180, 0, 256]).ravel().astype(np.float64)
    hist /= max(hist.sum(), 1e-12)
    gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    edges = cv2.Canny(gray, 50, 150)
    density = np.count_nonzero(edges[mask]) / float(area)
    gx = cv2.Sobel(gray, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(gray, cv2.CV_32F, 0, 1, ksize=3)
    mag, ang = cv2.cartToPolar(gx, gy, angleInDegrees=True)
    bins = (np.mod(ang[mask], 180.0) / 22.5).astype(np.int64).clip(0, 7)
    orient = np.bincount(bins, weights=mag[mask].astype(np.float64), minlength=8)
    total = orient.sum()
    orient = orient / total if total > 0 else np.zeros(8)
    return np.concatenate([geometry, hu, hist, [density], orient])


def gallery_visual_descriptor(descriptors: Sequence[np.ndarray]) -> np.ndarray:
    """Mean of snapshot descriptors (Eq. 4.20, agg = mean).

    Raises:
        ValueError: no descriptor, or one not of shape (54,).
    """
    if len(descriptors) == 0:
        raise ValueError("an object-level visual descriptor needs at least one snapshot")
    arr = np.stack([np.asarray(d, dtype=np.float64) for d in descriptors])
    if arr.shape[1:] != (VISUAL_DIM,):
        raise ValueError(f"snapshot descriptors have shape {arr.shape[1:]}, expected ({VISUAL_DIM},)")
    return arr.mean(axis=0)
