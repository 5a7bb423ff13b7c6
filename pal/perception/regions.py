"""Region operations of the geometric segmenter: depth and colour cuts, hole filling, metric size.

The functions work on whole images (or crops) at once, vectorised: one pass per frame, not
one per object.

- :func:`depth_discontinuities`: the farther pixel of every 4-neighbour depth jump larger than
  a (per-pixel) threshold; pairs with an invalid pixel are not jumps.
- :func:`colour_depth_edges`: colour edges (Canny) that coincide with depth evidence, a weak
  step (more than ``k`` sigma) or a concave crease (the pixel lies behind the local mean
  surface): where two touching objects meet. Colour edges alone (print on a box) do not cut.
- :func:`supported_colour_edges`: whole curves of colour edges that touch evidence of a
  boundary (a jump or a concave crease between two objects): the boundary between touching
  objects of the same height, whose coplanar tops have no depth evidence of their own.
- :func:`bridge_invalid`: invalid-depth gaps of at most ``radius`` pixels between foreground
  pixels of similar depth join the foreground (the dark rim of a can between its lid and its
  body); a gap between a near and a far surface (a monitor's edge against the wall behind it)
  is not bridged.
- :func:`fill_invalid_holes`: invalid-depth holes enclosed by a mask join it (a hole with
  valid depth is background seen through the object and stays out).
- :func:`merge_small`: pieces below the minimum size join the neighbouring piece they share
  the longest border with (cuts along texture never leave slivers behind), optionally only
  across smooth borders (a small object behind a depth step stays apart).
- :func:`metric_areas`: each piece's visible surface area ``sum z² / (fx fy)``, m², the size
  rule of the segmenter (pixels shrink with distance, metres do not).
"""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

__all__ = [
    "bridge_invalid",
    "colour_depth_edges",
    "depth_discontinuities",
    "fill_invalid_holes",
    "merge_small",
    "metric_area",
    "metric_areas",
    "smooth_pairs",
    "supported_colour_edges",
]

_CROSS = np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]], np.uint8)


def depth_discontinuities(depth: np.ndarray, threshold: np.ndarray | float) -> np.ndarray:
    """Pixels on the far side of a depth jump between valid 4-neighbours.

    Only the farther pixel of a jump is marked, so an occluding object keeps its full silhouette
    and the occluded one loses a one-pixel rim along the occlusion boundary. A pair with an
    invalid pixel (depth 0) is never a jump.

    Args:
        depth: (H, W) float32 metres, 0 = invalid.
        threshold: scalar or (H, W) jump threshold, metres.

    Returns:
        (H, W) bool.
    """
    cut = np.zeros(depth.shape, dtype=bool)
    thr = np.broadcast_to(np.asarray(threshold, dtype=np.float32), depth.shape)
    valid = depth > 0
    dx = depth[:, 1:] - depth[:, :-1]
    jump = (np.abs(dx) > np.minimum(thr[:, 1:], thr[:, :-1])) & valid[:, 1:] & valid[:, :-1]
    cut[:, 1:] |= jump & (dx > 0)
    cut[:, :-1] |= jump & (dx < 0)
    dy = depth[1:, :] - depth[:-1, :]
    jump = (np.abs(dy) > np.minimum(thr[1:, :], thr[:-1, :])) & valid[1:, :] & valid[:-1, :]
    cut[1:, :] |= jump & (dy > 0)
    cut[:-1, :] |= jump & (dy < 0)
    return cut


def colour_depth_edges(
    gray: np.ndarray,
    depth: np.ndarray,
    sigma: np.ndarray,
    region: np.ndarray,
    *,
    low: float = 40.0,
    high: float = 120.0,
    k: float = 2.0,
) -> np.ndarray:
    """Colour edges inside ``region`` backed by a weak depth step or a concave crease.

    Args:
        gray: (h, w) uint8 grey levels.
        depth: (h, w) float32 metres (0 = invalid).
        sigma: (h, w) float32 depth noise, metres.
        region: (h, w) bool, where cuts may fall (the foreground).
        low: Canny's lower hysteresis threshold, grey levels.
        high: Canny's upper hysteresis threshold, grey levels.
        k: a step or crease counts when larger than ``k`` sigma.

    Returns:
        (h, w) bool cut pixels (a subset of ``region``).
    """
    edges = cv2.Canny(gray, low, high, L2gradient=True) > 0
    edges &= region & (depth > 0)
    vs, us = np.nonzero(edges)
    if vs.size == 0:
        return edges
    valid = (depth > 0).astype(np.float32)
    mean = cv2.blur(depth, (5, 5)) / np.maximum(cv2.blur(valid, (5, 5)), 1e-6)
    z = depth[vs, us]
    thr = k * sigma[vs, us]
    crease = (z - mean[vs, us]) > thr  # behind the local mean surface: concave
    h, w = depth.shape
    step = np.zeros(vs.size, dtype=bool)
    for dv, du in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        v2, u2 = np.clip(vs + dv, 0, h - 1), np.clip(us + du, 0, w - 1)
        zn = depth[v2, u2]
        step |= (zn > 0) & (np.abs(zn - z) > 2.0 * thr)
    out = np.zeros_like(edges)
    keep = crease | step
    out[vs[keep], us[keep]] = True
    return out


def supported_colour_edges(
    rgb: np.ndarray,
    region: np.ndarray,
    evidence: np.ndarray,
    reach: int,
    *,
    low: float = 40.0,
    high: float = 120.0,
    min_touch: int = 3,
) -> np.ndarray:
    """Colour edge curves inside ``region`` that touch geometric evidence of a boundary.

    Two objects of the same height that touch share a colour boundary but no depth step on
    their coplanar tops; the crease between their sides (or a jump) marks the same boundary a
    little further on. A curve of colour edges (Canny on the colour image, 8-connected) is
    kept whole when at least ``min_touch`` of its pixels lie within ``reach`` pixels of
    ``evidence``; print inside one object's face touches no such evidence and is not kept.

    Args:
        rgb: (h, w, 3) uint8 colour image.
        region: (h, w) bool, where cuts may fall (the foreground).
        evidence: (h, w) bool boundary pixels between objects (jumps, concave creases) away
            from the support.
        reach: pixels.
        low: Canny's lower hysteresis threshold, grey levels.
        high: Canny's upper hysteresis threshold, grey levels.
        min_touch: pixels of a curve near the evidence for the curve to count.

    Returns:
        (h, w) bool cut pixels (a subset of ``region``).
    """
    out = np.zeros(region.shape, dtype=bool)
    rows, cols = np.flatnonzero(region.any(axis=1)), np.flatnonzero(region.any(axis=0))
    if rows.size == 0 or not evidence.any():
        return out
    box = (slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1))  # Canny on the region's box only
    edges = (cv2.Canny(np.ascontiguousarray(rgb[box]), low, high, L2gradient=True) > 0) & region[box]
    if not edges.any():
        return out
    n, curves = cv2.connectedComponents(edges.view(np.uint8), connectivity=8, ltype=cv2.CV_32S)
    k = 2 * reach + 1
    near = cv2.dilate(evidence[box].view(np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))) > 0
    touch = np.bincount(curves[near & edges], minlength=n)
    keep = touch >= min_touch
    keep[0] = False
    out[box] = keep[curves]
    return out


def bridge_invalid(
    foreground: np.ndarray, depth: np.ndarray, radius: int, jump: Callable[[np.ndarray], np.ndarray]
) -> np.ndarray:
    """``foreground`` plus the invalid pixels its closing (``radius`` px) covers between similar depths.

    An invalid pixel covered by the morphological closing joins the foreground only when the
    foreground depths within ``radius`` of it span less than ``jump(near)`` (metres, the
    discontinuity threshold at the nearer of them): the gap lies inside one surface, not between
    two.

    Args:
        foreground: (H, W) bool.
        depth: (H, W) float32 metres, 0 = invalid.
        radius: gap half-width bridged, pixels (0: nothing is bridged).
        jump: the depth-discontinuity threshold (metres) as a function of depth (metres, array).
    """
    if radius < 1:
        return foreground
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
    closed = cv2.morphologyEx(foreground.view(np.uint8), cv2.MORPH_CLOSE, kernel).view(bool)
    gap = closed & (depth <= 0) & ~foreground
    if not gap.any():
        return foreground
    far = cv2.dilate(np.where(foreground, depth, 0).astype(np.float32), kernel)
    near = cv2.erode(np.where(foreground, depth, np.float32(1e6)).astype(np.float32), kernel)
    ys, xs = np.nonzero(gap)
    n = near[ys, xs]
    ok = (far[ys, xs] - n) < jump(n)
    out = foreground.copy()
    out[ys[ok], xs[ok]] = True
    return out


def fill_invalid_holes(mask: np.ndarray, invalid: np.ndarray) -> np.ndarray:
    """``mask`` with its enclosed holes of invalid depth filled (valid holes stay out).

    Args:
        mask: (h, w) bool, a tight crop of one piece.
        invalid: (h, w) bool, pixels without depth.
    """
    h, w = mask.shape
    outside = np.zeros((h + 2, w + 2), np.uint8)
    outside[1:-1, 1:-1] = ~mask
    flood = np.zeros((h + 4, w + 4), np.uint8)
    cv2.floodFill(outside, flood, (0, 0), 2)
    holes = outside[1:-1, 1:-1] == 1  # not the mask, not reached from outside
    return mask | (holes & invalid)


def merge_small(
    labels: np.ndarray, keep: np.ndarray, joinable: tuple[np.ndarray, np.ndarray] | None = None
) -> np.ndarray:
    """Give every piece not in ``keep`` to the kept neighbour it shares the longest border with.

    Args:
        labels: (h, w) int32 piece labels, 0 = none.
        keep: (n,) bool per label (index 0 ignored): pieces large enough to stand alone.
        joinable: optional ((h, w - 1), (h - 1, w)) bool: which horizontal and vertical
            neighbour pairs may count as border (e.g. not across a depth discontinuity). With
            it, small pieces without a kept neighbour join the small pieces they border (the
            fragments of one printed face become one piece again) instead of being removed.

    Returns:
        (h, w) int32 labels: without ``joinable`` every piece is a kept one (small pieces
        without a kept 4-neighbour are removed: label 0).
    """
    n = keep.shape[0]
    if keep[1:].all():
        return labels
    pairs = []
    pairs_of = ((labels[:, 1:], labels[:, :-1]), (labels[1:, :], labels[:-1, :]))
    for k, (x, y) in enumerate(pairs_of):
        sel = (x != y) & (x > 0) & (y > 0)
        if joinable is not None:
            sel &= joinable[k]
        pairs.append((x[sel], y[sel]))
    a = np.concatenate([pairs[0][0], pairs[1][0]])
    b = np.concatenate([pairs[0][1], pairs[1][1]])
    a, b = np.concatenate([a, b]), np.concatenate([b, a])
    ok = ~keep[a] & keep[b]  # border of a small piece with a kept one
    target = np.arange(n)
    if joinable is None:
        target[~keep] = 0
    if ok.any():
        border = np.bincount(a[ok] * n + b[ok], minlength=n * n).reshape(n, n)
        small = np.flatnonzero(~keep)
        best = border[small].argmax(axis=1)
        has = border[small, best] > 0
        target[small[has]] = best[has]
    if joinable is not None:
        alone = ~keep & (target == np.arange(n))  # small pieces that found no kept neighbour
        both = alone[a] & alone[b]
        if both.any():
            graph = csr_matrix((np.ones(int(both.sum())), (a[both], b[both])), shape=(n, n))
            _, group = connected_components(graph, directed=False)
            first = np.full(n, n, np.int64)
            np.minimum.at(first, group[alone], np.flatnonzero(alone))
            target[alone] = first[group[alone]]
    target[0] = 0
    return target[labels]


def metric_areas(labels: np.ndarray, n: int, depth: np.ndarray, fx: float, fy: float) -> np.ndarray:
    """(n,) visible surface area of each label, m²: ``sum z² / (fx fy)`` (fronto-parallel).

    Pixels without depth count at the mean ``z²`` of the label's pixels with depth.
    """
    on = labels > 0
    flat = labels[on]
    z = depth[on].astype(np.float64)
    z2, valid = z * z, z > 0
    total = np.bincount(flat, minlength=n)
    with_depth = np.bincount(flat, weights=valid.astype(np.float64), minlength=n)
    sums = np.bincount(flat, weights=z2, minlength=n)
    mean = np.divide(sums, with_depth, out=np.zeros(n), where=with_depth > 0)
    return mean * total / (fx * fy)


def metric_area(depth: np.ndarray, mask: np.ndarray, fx: float, fy: float) -> float:
    """Area of the visible surface under ``mask`` (h, w) bool, m² (see :func:`metric_areas`)."""
    return float(metric_areas(mask.astype(np.int32), 2, depth, fx, fy)[1])


def smooth_pairs(depth: np.ndarray, jump: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal (H, W-1) and vertical (H-1, W) neighbour pairs with valid depths closer than ``jump``.

    Args:
        depth: (H, W) float32 metres, 0 = invalid.
        jump: (H, W) depth-discontinuity threshold, metres.

    Returns:
        the ``joinable`` pairs of :func:`merge_small`.
    """
    ok = depth > 0
    out = []
    for a, b, ta, tb, va, vb in (
        (depth[:, 1:], depth[:, :-1], jump[:, 1:], jump[:, :-1], ok[:, 1:], ok[:, :-1]),
        (depth[1:], depth[:-1], jump[1:], jump[:-1], ok[1:], ok[:-1]),
    ):
        out.append(va & vb & (np.abs(a - b) < np.minimum(ta, tb)))
    return out[0], out[1]
