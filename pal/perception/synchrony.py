"""Kinematic synchrony of object pairs (:mod:`pal.perception.relations`): do two objects move together?

Over the last ``window`` seconds of centroid measurements shared by both objects, the uncentred
correlation of their finite-difference velocities ``Σ v_i·v_j / sqrt(Σ|v_i|² Σ|v_j|²)`` in
[-1, 1] (1: moving together). None when both move slower than ``min_speed`` (undefined) or
with fewer than 3 shared times; 0.0 when only one moves. Repeated timestamps count once, the
last one (:func:`distinct_history`). :func:`pair_synchrony` computes it for all of a frame's
pairs at once: the histories are laid on the frame times they share, and each pair's
velocities run between consecutive times both objects were measured; sums over a pair's
velocities may differ from one pair at a time in the last bits (the order of summation).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

__all__ = ["distinct_history", "pair_synchrony", "velocity_correlation"]


def distinct_history(history: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """The (timestamps (N,) s, positions (N, 3) m) history with each time once (its last sample), sorted."""
    t, p = np.asarray(history[0], dtype=np.float64), np.asarray(history[1], dtype=np.float64).reshape(-1, 3)
    if t.size < 2:
        return t, p
    rev = t[::-1]
    _, first = np.unique(rev, return_index=True)  # first occurrence in reverse = last one
    keep = (t.size - 1 - first)[np.argsort(t[t.size - 1 - first])]
    return t[keep], p[keep]


def velocity_correlation(
    a: tuple[np.ndarray, np.ndarray],
    b: tuple[np.ndarray, np.ndarray],
    now: float,
    window: float,
    min_speed: float,
) -> float | None:
    """The synchrony (module docstring) of two histories already made distinct (:func:`distinct_history`).

    Args:
        a: (timestamps (N,) s, positions (N, 3) m) of the first object.
        b: the same of the second.
        now: the current time, s.
        window: how far back shared times count, s.
        min_speed: below this mean speed an object counts as still, m/s.
    """
    (ta, pa), (tb, pb) = a, b
    if ta.size < 3 or tb.size < 3:
        return None
    common, ia, ib = np.intersect1d(ta, tb, assume_unique=True, return_indices=True)
    recent = common >= now - window
    common, ia, ib = common[recent], ia[recent], ib[recent]
    if common.size < 3:
        return None
    dt = np.diff(common)[:, None]
    va = np.diff(pa[ia], axis=0) / dt
    vb = np.diff(pb[ib], axis=0) / dt
    sa, sb = np.linalg.norm(va, axis=1).mean(), np.linalg.norm(vb, axis=1).mean()
    moving_a, moving_b = sa >= min_speed, sb >= min_speed
    if not moving_a and not moving_b:
        return None
    if not (moving_a and moving_b):
        return 0.0
    return float(np.sum(va * vb) / np.sqrt(np.sum(va * va) * np.sum(vb * vb)))


def pair_synchrony(
    pairs: Sequence[tuple[int, int]],
    histories: Mapping[int, tuple[np.ndarray, np.ndarray]],
    now: float,
    window: float,
    min_speed: float,
) -> list[float | None]:
    """:func:`velocity_correlation` of each pair (a, b) at once (arguments as there).

    ``histories`` holds the distinct histories by object id; an object without one has none.
    """
    out: list[float | None] = [None] * len(pairs)
    ids = sorted({i for pair in pairs for i in pair if i in histories and histories[i][0].size >= 3})
    lo = now - window
    times = np.unique(np.concatenate([histories[i][0] for i in ids])) if ids else np.zeros(0)
    times = times[times >= lo]
    use = [k for k, (a, b) in enumerate(pairs) if a in histories and b in histories]
    row = {i: k for k, i in enumerate(ids)}
    use = [k for k in use if pairs[k][0] in row and pairs[k][1] in row]
    if times.size < 3 or not use:
        return out
    P = np.zeros((len(ids), times.size, 3))
    present = np.zeros((len(ids), times.size), dtype=bool)
    for i, k in row.items():
        t, p = histories[i]
        sel = t >= lo
        j = np.searchsorted(times, t[sel])
        P[k, j], present[k, j] = p[sel], True
    ia = np.array([row[pairs[k][0]] for k in use])
    ib = np.array([row[pairs[k][1]] for k in use])
    shared = present[ia] & present[ib]  # (Q, T)
    last = np.maximum.accumulate(np.where(shared, np.arange(times.size), -1), axis=1)
    prev = np.concatenate([np.full((len(use), 1), -1), last[:, :-1]], axis=1)
    q, j = np.nonzero(shared & (prev >= 0))  # a velocity ends at each such shared time
    pj = prev[q, j]
    dt = (times[j] - times[pj])[:, None]
    va, vb = (P[ia[q], j] - P[ia[q], pj]) / dt, (P[ib[q], j] - P[ib[q], pj]) / dt
    n = np.maximum(np.bincount(q, minlength=len(use)), 1)
    sa = np.bincount(q, np.linalg.norm(va, axis=1), len(use)) / n
    sb = np.bincount(q, np.linalg.norm(vb, axis=1), len(use)) / n
    ab, aa, bb = (np.bincount(q, np.sum(x * y, axis=1), len(use)) for x, y in ((va, vb), (va, va), (vb, vb)))
    enough = shared.sum(axis=1) >= 3
    for m, k in enumerate(use):
        moving_a, moving_b = sa[m] >= min_speed, sb[m] >= min_speed
        if not enough[m] or not (moving_a or moving_b):
            continue
        out[k] = float(ab[m] / np.sqrt(aa[m] * bb[m])) if moving_a and moving_b else 0.0
    return out
