"""The geometry of many object pairs at once, for the relational layer (:mod:`pal.perception.relations`).

A frame relates a few dozen pairs; one pair at a time, each relation is a handful of tiny
array operations whose cost is the per-call overhead. These functions compute them for all
pairs in one pass with the definitions of :mod:`pal.perception.grounding`:
:func:`displacements` (centroid differences, distances, directions), :func:`surface_gaps`
(footprint-box gaps, and the rim points' nearest distance only where the boxes are close)
and :func:`grade_pairs` (the graded predicates of :func:`pal.perception.grounding.grade`).
Results equal the per-pair ones to rounding (the standard normal CDF is scipy's ``ndtr``
instead of ``math.erfc``; norms sum in another order).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.spatial import cKDTree
from scipy.special import ndtr

from pal.perception.grounding import PREDICATES, GroundingConfig, ObjectGeometry

__all__ = ["displacements", "grade_pairs", "surface_gaps"]


def displacements(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``b - a`` of (P, 3) centroids, metres: (displacements (P, 3), distances (P,), unit directions (P, 3)).

    A zero displacement has a zero direction.
    """
    d = b - a
    dist = np.linalg.norm(d, axis=1)
    direc = np.divide(d, dist[:, None], out=np.zeros_like(d), where=dist[:, None] > 0)
    return d, dist, direc


def _boxes(geoms: Sequence[ObjectGeometry]) -> tuple[np.ndarray, np.ndarray]:
    lo = np.array([g.lo for g in geoms], dtype=np.float64).reshape(-1, 2)
    hi = np.array([g.hi for g in geoms], dtype=np.float64).reshape(-1, 2)
    return lo, hi


def surface_gaps(
    pairs: Sequence[tuple[int, int]],
    geometry: dict[int, ObjectGeometry],
    config: GroundingConfig,
    trees: dict[int, cKDTree],
) -> np.ndarray:
    """Surface gaps (P,) of the pairs (a, b) of objects with geometry, metres.

    The footprint boxes' gap (:func:`pal.perception.grounding.box_gap`) where it exceeds
    ``touch_gap + 0.05`` (such surfaces cannot touch), else the smallest distance between the
    objects' rim points (:func:`pal.perception.grounding.surface_gap`; ``a``'s k-d tree is
    kept in ``trees``).
    """
    if not pairs:
        return np.zeros(0)
    lo_a, hi_a = _boxes([geometry[a] for a, _ in pairs])
    lo_b, hi_b = _boxes([geometry[b] for _, b in pairs])
    gap = np.linalg.norm(np.maximum(0.0, np.maximum(lo_a - hi_b, lo_b - hi_a)), axis=1)
    for k in np.flatnonzero(gap <= config.touch_gap + 0.05):
        a, b = pairs[k]
        if a not in trees:
            trees[a] = cKDTree(geometry[a].surface)
        gap[k] = float(trees[a].query(geometry[b].surface, k=1)[0].min())
    return gap


def grade_pairs(
    a: Sequence[ObjectGeometry], b: Sequence[ObjectGeometry], config: GroundingConfig, gap: np.ndarray
) -> np.ndarray:
    """:func:`pal.perception.grounding.grade` of the ordered pairs ``(a[k], b[k])`` at once.

    Args:
        a: first objects' geometry (P,).
        b: second objects' geometry (P,).
        config: the predicates' scales.
        gap: (P,) the pairs' surface gaps, metres (:func:`surface_gaps`).

    Returns:
        (P, 5) grades in [0, 1], columns in the order of :data:`~pal.perception.grounding.PREDICATES`.
    """
    lo_a, hi_a = _boxes(a)
    lo_b, hi_b = _boxes(b)
    pa = np.array([g.position for g in a], dtype=np.float64).reshape(-1, 3)
    pb = np.array([g.position for g in b], dtype=np.float64).reshape(-1, 3)
    bot_a, top_a = np.array([g.bottom for g in a]), np.array([g.top for g in a])
    bot_b, top_b = np.array([g.bottom for g in b]), np.array([g.top for g in b])
    sab = np.hypot([g.sigma for g in a], [g.sigma for g in b])
    size = (hi_a - lo_a + hi_b - lo_b) / 4.0
    s_x, s_y = np.sqrt(sab**2 + size[:, 0] ** 2), np.sqrt(sab**2 + size[:, 1] ** 2)
    left = ndtr((pb[:, 0] - pa[:, 0]) / s_x)
    front = ndtr((pb[:, 1] - pa[:, 1]) / s_y)
    d = config.near_distance
    vertical = np.maximum(0.0, np.maximum(bot_a - top_b, bot_b - top_a))
    apart = np.maximum(0.0, np.maximum(lo_a - hi_b, lo_b - hi_a))
    box = np.sqrt(apart[:, 0] ** 2 + apart[:, 1] ** 2 + vertical**2)
    near = ndtr((d - box) / (0.25 * d + sab))
    s_on = config.on_tolerance / 2.0 + sab
    inter = np.clip(np.minimum(hi_a, hi_b) - np.maximum(lo_a, lo_b), 0.0, None)
    overlap = np.prod(inter, axis=1) / np.prod(np.maximum(hi_a - lo_a, 1e-3), axis=1)
    on = np.where(
        pa[:, 2] > pb[:, 2], ndtr((config.on_tolerance - np.abs(bot_a - top_b)) / s_on) * overlap, 0.0
    )
    touching = ndtr((config.touch_gap - gap) / (sab * 0.5 + 0.005))
    out = np.stack([near, np.minimum(on, 1.0), left, front, touching], axis=1)
    assert out.shape[1] == len(PREDICATES)
    return out
