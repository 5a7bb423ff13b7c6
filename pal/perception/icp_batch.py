"""Many objects' poses scored at once: :func:`pal.perception.icp.icp_score` batched over objects.

Π checks the egomotion prediction of every static object in every frame
(:mod:`pal.perception.pose_predicted`). Each check is a handful of small array operations on a
model of about 100-160 points, so one object at a time the cost is the per-call overhead, not
the arithmetic. :func:`icp_scores` stacks the models of all objects (each with its own pose,
live mask box and grey levels) and computes the same terms in one pass: projective
correspondences on the live depth, the depth residuals, free-space violations, the photometric
residuals, the covariance ``s^2 (J^T J)^-1`` and the geometric condition number (the
definitions are those of :mod:`pal.perception.icp`). Only what differs per object in its data
stays a loop over objects: the bilinear samples of each object's own smoothed grey-level crop
and the medians of its residuals. Per-point quantities are computed elementwise exactly as
one object at a time; sums over an object's points may differ in the last bits (the order of
summation), so every result equals :func:`icp_score`'s to rounding.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pal.perception.frames import RGBDFrame
from pal.perception.icp import IcpConfig, IcpFit, _checked, _terms
from pal.perception.icp_terms import LiveSurface, Photometric, cross, surface_normals
from pal.perception.masks import Mask
from pal.perception.noise import DepthNoise

__all__ = ["BatchMatch", "PhotoStack", "ScoreItem", "associate_all", "icp_scores", "scores_with_terms"]


@dataclass(frozen=True, eq=False)
class ScoreItem:
    """One object's pose to score (the arguments of :func:`pal.perception.icp.icp_score`).

    Attributes:
        model: (M, 3) object-frame surface points, metres.
        T: (4, 4) ``camera_from_object`` to score.
        mask: the object's live mask.
        model_gray: (M,) smoothed grey levels of the model points, or None (depth only).
        step: the model's grid step, pixels.
    """

    model: np.ndarray
    T: np.ndarray
    mask: Mask
    model_gray: np.ndarray | None = None
    step: int = 1


def _group_index(groups: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(the groups present, the first row of each) of sorted ``groups`` (P,), for :func:`_group_sum`."""
    return np.unique(groups, return_index=True)


def _group_sum(
    values: np.ndarray, groups: np.ndarray, n: int, index: tuple[np.ndarray, np.ndarray] | None = None
) -> np.ndarray:
    """Sums of ``values`` (P, ...) over the rows of each group; ``groups`` (P,) sorted, in [0, n).

    ``index``: :func:`_group_index` of ``groups`` when already computed.
    """
    out = np.zeros((n, *values.shape[1:]))
    if len(values):
        idx, start = _group_index(groups) if index is None else index
        out[idx] = np.add.reduceat(values, start, axis=0)
    return out


def _median_exact(x: np.ndarray) -> float:
    """``float(np.median(x))`` of a non-empty 1-D array, without its call overhead."""
    s = np.sort(x)
    k = len(s) // 2
    return float(s[k]) if len(s) % 2 else float((s[k - 1] + s[k]) / 2.0)


def _lookup(
    frame: RGBDFrame,
    U: np.ndarray,
    V: np.ndarray,
    box: tuple[np.ndarray, np.ndarray],
    member: np.ndarray,
    b: int,
    max_jump: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Live points and normals at full-frame pixels (U, V) (as ``LiveSurface.lookup``).

    Args:
        frame: the live frame.
        U: (N,) int64 full-frame pixel columns.
        V: (N,) int64 full-frame pixel rows.
        box: (N, 2) top-left and (N, 2) end corners of each pixel's live box, pixels.
        member: (N,) whether each pixel may match (in its object's live mask, or any pixel).
        b: the normals' baseline, pixels.
        max_jump: largest depth step across it, per pixel and metre of depth.

    Returns:
        (ok (N,), points (P, 3) metres, unit normals (P, 3) facing the camera) of the ok pixels.
    """
    lo, hi = box
    ok = member & (U >= lo[:, 0] + b) & (V >= lo[:, 1] + b) & (U < hi[:, 0] - b) & (V < hi[:, 1] - b)
    ok[ok] = frame.depth[V[ok], U[ok]] > 0
    good, P, n = surface_normals(frame.depth, U[ok], V[ok], (0, 0), frame.K, b, max_jump)
    keep = np.zeros(len(ok), dtype=bool)
    keep[np.flatnonzero(ok)[good]] = True
    return keep, P, n


class PhotoStack:
    """The photometric terms of several objects stacked for one-pass sampling (``Photometric`` batched).

    Each object's (h, w, 3) grey levels and gradients are flattened into one (sum h w, 3)
    buffer at offset ``base``, its model grey levels into one (sum M,) buffer at ``gray_base``.
    """

    def __init__(self, photos: Sequence[Photometric | None]) -> None:
        self.has = np.array([p is not None for p in photos], dtype=bool)
        got = [p for p in photos if p is not None]
        self.x0 = np.array([p.x0 if p is not None else 0 for p in photos], dtype=np.float64)
        self.y0 = np.array([p.y0 if p is not None else 0 for p in photos], dtype=np.float64)
        shape = np.array([p.img.shape if p is not None else (0, 0) for p in photos], dtype=np.int64).reshape(-1, 2)
        self.wh = shape[:, ::-1].astype(np.float64)
        self.width = shape[:, 1]
        sizes = shape[:, 0] * shape[:, 1]
        self.base = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)
        self.levels = np.concatenate([p.levels.reshape(-1, 3) for p in got]) if got else np.zeros((0, 3), np.float32)
        lengths = np.array([len(p.model_gray) if p is not None else 0 for p in photos], dtype=np.int64)
        self.gray_base = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64)
        self.gray = np.concatenate([p.model_gray for p in got]) if got else np.zeros(0)
        self.sigma = np.array([p.sigma if p is not None else 1.0 for p in photos])

    def sample(self, g: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Bilinear samples (N, 3) of the objects ``g`` (N,) at their crops' float pixels (``bilinear``)."""
        u0, v0 = np.floor(u).astype(np.int64), np.floor(v).astype(np.int64)
        a, b = (u - u0)[:, None], (v - v0)[:, None]
        w = self.width[g]
        i = self.base[g] + v0 * w + u0
        L = self.levels
        return L[i] * (1 - a) * (1 - b) + L[i + 1] * a * (1 - b) + L[i + w] * (1 - a) * b + L[i + w + 1] * a * b


def _group_medians(values: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """The median (``quantiles.median``) of each group's values, per value (N,); ``groups`` sorted."""
    order = np.lexsort((values, groups))
    s = values[order]
    _, start, count = np.unique(groups, return_index=True, return_counts=True)
    pos = 0.5 * (count - 1)
    lo = np.floor(pos).astype(np.int64)
    hi = np.minimum(lo + 1, count - 1)
    med = s[start + lo] + (s[start + hi] - s[start + lo]) * (pos - lo)
    return np.repeat(med, count)


def _photometric(
    stack: PhotoStack,
    g: np.ndarray,
    sel: np.ndarray,
    y: np.ndarray,
    X: np.ndarray,
    K: np.ndarray,
    use: np.ndarray | None = None,
):
    """Whitened grey-level residuals and Jacobian rows of all objects' agreeing points (``Photometric.__call__``).

    Args:
        stack: the objects' photometric terms.
        g: (P,) sorted objects of the points (indices into ``stack``).
        sel: (P,) the points' indices in their object's model.
        y: (P, 3) the points rotated, metres.
        X: (P, 3) the points moved, metres.
        K: (3, 3) intrinsics.
        use: (n,) the objects whose terms are wanted (default: those with grey levels).

    Returns:
        (residuals (Q,), Jacobian rows (Q, 6), their objects (Q,), in object order).
    """
    z = X[:, 2]
    wh = stack.wh
    u = K[0, 0] * X[:, 0] / z + K[0, 1] * X[:, 1] / z + K[0, 2] - stack.x0[g]
    v = K[1, 1] * X[:, 1] / z + K[1, 2] - stack.y0[g]
    has = stack.has if use is None else stack.has & use
    ok = has[g] & (u >= 0) & (v >= 0) & (u < wh[g, 0] - 1) & (v < wh[g, 1] - 1)
    u, v, z, y, X, sel, g = u[ok], v[ok], z[ok], y[ok], X[ok], sel[ok], g[ok]
    sampled = stack.sample(g, u, v)
    r = sampled[:, 0] - stack.gray[stack.gray_base[g] + sel]
    if len(r):
        r = r - _group_medians(r, g)
    gr = sampled[:, 1:]
    zero = np.zeros_like(z)
    du = np.stack([K[0, 0] / z, zero, -K[0, 0] * X[:, 0] / z**2], axis=1)
    dv = np.stack([zero, K[1, 1] / z, -K[1, 1] * X[:, 1] / z**2], axis=1)
    gX = gr[:, :1] * du + gr[:, 1:] * dv
    J = np.concatenate([cross(y, gX), gX], axis=1)
    sigma = stack.sigma[g]
    return r / sigma, J / sigma[:, None], g


def _covariances(H: np.ndarray, s2: np.ndarray) -> list[np.ndarray | None]:
    """``s2 H^-1`` symmetrised per object, None where singular or not a covariance (``icp._covariance``)."""
    try:
        inv = np.linalg.inv(H)
    except np.linalg.LinAlgError:
        inv = None
    out: list[np.ndarray | None] = []
    for i in range(len(H)):
        try:
            cov = s2[i] * (np.linalg.inv(H[i]) if inv is None else inv[i])
        except np.linalg.LinAlgError:
            out.append(None)
            continue
        cov = 0.5 * (cov + cov.T)
        out.append(cov if np.all(np.isfinite(cov)) and not np.any(np.diag(cov) < 0) else None)
    return out


def _conditions(
    H_depth: np.ndarray, X: np.ndarray, g: np.ndarray, t: np.ndarray, count: np.ndarray
) -> np.ndarray:
    """Geometric condition numbers of the depth terms per object (``icp._condition``)."""
    n = len(H_depth)
    mean = _group_sum(X, g, n) / np.maximum(count, 1)[:, None]
    c = X - mean[g]
    L = np.sqrt(_group_sum(np.sum(c**2, axis=1), g, n) / np.maximum(count, 1))
    L = np.where(L > 0, L, 1.0)
    mt = mean - t
    A = np.tile(np.eye(6), (n, 1, 1))
    A[:, :3, :3] /= L[:, None, None]
    skew = np.zeros((n, 3, 3))
    skew[:, 0, 1], skew[:, 0, 2], skew[:, 1, 2] = -mt[:, 2], mt[:, 1], -mt[:, 0]
    skew[:, 1, 0], skew[:, 2, 0], skew[:, 2, 1] = mt[:, 2], -mt[:, 1], mt[:, 0]
    A[:, 3:, :3] = skew / L[:, None, None]
    Hc = np.transpose(A, (0, 2, 1)) @ H_depth @ A
    ev = np.linalg.eigvalsh(0.5 * (Hc + np.transpose(Hc, (0, 2, 1))))
    pinned = ev[:, 0] > 1e-12 * np.maximum(ev[:, -1], 1e-300)
    return np.where(pinned, np.sqrt(ev[:, -1] / np.where(pinned, ev[:, 0], 1.0)), np.inf)


@dataclass(frozen=True, eq=False)
class BatchMatch:
    """Projective correspondences of several objects' models at once (``icp_terms.associate`` batched).

    Attributes:
        g: (N,) object of each stacked model point.
        y: (N, 3) the points rotated, ``X`` (N, 3) moved, metres.
        U: (N,) int64 full-frame pixel columns, ``V`` (N,) rows, where they project.
        inside: (N,) in front of the camera and inside their object's live box.
        idx: (P,) the matched stacked points, ``gi`` (P,) their objects.
        q: (P, 3) live points and ``n`` (P, 3) live unit normals of the matches, metres.
    """

    g: np.ndarray
    y: np.ndarray
    X: np.ndarray
    U: np.ndarray
    V: np.ndarray
    inside: np.ndarray
    idx: np.ndarray
    gi: np.ndarray
    q: np.ndarray
    n: np.ndarray


def associate_all(
    models: Sequence[np.ndarray],
    R: np.ndarray,
    t: np.ndarray,
    lives: Sequence[LiveSurface],
    frame: RGBDFrame,
    cfg: IcpConfig,
) -> BatchMatch:
    """Move each model ``k`` by (``R[k]``, ``t[k]``), project it and pair it with its live surface.

    Args:
        models: per object its (M_k, 3) object-frame points, metres.
        R: (n, 3, 3) rotations.
        t: (n, 3) translations, metres.
        lives: per object its :class:`~pal.perception.icp_terms.LiveSurface`.
        frame: the live frame.
        cfg: the dense fit's parameters (``grow_px``, ``normal_px``).
    """
    n = len(models)
    sizes = np.array([len(m) for m in models], dtype=np.int64)
    g_all = np.repeat(np.arange(n), sizes)
    y_all = np.concatenate([m @ R[k].T for k, m in enumerate(models)]) if sizes.sum() else np.zeros((0, 3))
    X_all = y_all + t[g_all]
    lo = np.array([(lv.x0, lv.y0) for lv in lives], dtype=np.int64).reshape(-1, 2)
    hi = lo + np.array([(lv.w, lv.h) for lv in lives], dtype=np.int64).reshape(-1, 2)
    K = frame.K
    z_all = X_all[:, 2]
    zs = np.where(z_all > 1e-6, z_all, 1e-6)
    U = np.rint(K[0, 0] * X_all[:, 0] / zs + K[0, 1] * X_all[:, 1] / zs + K[0, 2]).astype(np.int64)
    V = np.rint(K[1, 1] * X_all[:, 1] / zs + K[1, 2]).astype(np.int64)
    inside = (
        (z_all > 1e-6) & (U >= lo[g_all, 0]) & (V >= lo[g_all, 1]) & (U < hi[g_all, 0]) & (V < hi[g_all, 1])
    )
    idx = np.flatnonzero(inside)
    gi = g_all[idx]
    member = np.ones(len(idx), dtype=bool)
    if round(cfg.grow_px * frame.width / 640) == 0:  # without a grown box: pixels of the live mask only
        for i, lv in enumerate(lives):
            s = np.flatnonzero(gi == i)
            member[s] = lv.valid[V[idx[s]] - lv.y0, U[idx[s]] - lv.x0]
    max_jump = lives[0].max_jump if lives else 0.0
    good, q, nrm = _lookup(frame, U[idx], V[idx], (lo[gi], hi[gi]), member, cfg.normal_px, max_jump)
    return BatchMatch(g_all, y_all, X_all, U, V, inside, idx[good], gi[good], q, nrm)


def icp_scores(
    items: Sequence[ScoreItem],
    frame: RGBDFrame,
    noise: DepthNoise | None = None,
    config: IcpConfig | None = None,
) -> list[IcpFit | None]:
    """``[icp_score(it.model, it.T, frame, it.mask, noise, config, it.model_gray, it.step) for it in items]`` in one pass.

    Args:
        items: the objects' models, poses, live masks, grey levels and grid steps.
        frame: the live frame.
        noise: the depth sensor's noise model.
        config: the dense fit's parameters.

    Returns:
        Per item, its fit scored at ``T`` (``iterations`` 0), or None when fewer than 6 model
        points find a live correspondence (as :func:`pal.perception.icp.icp_score`).

    Raises:
        ValueError: a model is not (M, 3), a pose not a finite (4, 4) matrix, or grey levels
            not (M,).
    """
    cfg, noise = config or IcpConfig(), noise or DepthNoise()
    if not items:
        return []
    checked = [_checked(it.model, it.T) for it in items]
    terms = [_terms(frame, it.mask, cfg, m, it.model_gray) for it, (m, _) in zip(items, checked, strict=True)]
    return scores_with_terms(items, checked, terms, frame, noise, cfg)


def scores_with_terms(
    items: Sequence[ScoreItem],
    checked: Sequence[tuple[np.ndarray, np.ndarray]],
    terms: Sequence[tuple[LiveSurface, Photometric | None]],
    frame: RGBDFrame,
    noise: DepthNoise,
    cfg: IcpConfig,
) -> list[IcpFit | None]:
    """:func:`icp_scores` with each item's checked (model, T) and live terms (``icp._terms``) given."""
    n = len(items)
    t = np.array([T[:3, 3] for _, T in checked]).reshape(-1, 3)
    R = np.array([T[:3, :3] for _, T in checked]).reshape(-1, 3, 3)
    bm = associate_all([m for m, _ in checked], R, t, [lv for lv, _ in terms], frame, cfg)
    idx, gi = bm.idx, bm.gi
    matched = np.bincount(gi, minlength=n)
    ib = np.flatnonzero(bm.inside)
    zp = bm.X[ib, 2]
    zl = frame.depth[bm.V[ib], bm.U[ib]].astype(np.float64)
    behind = (zl > 0) & (zl > zp + 3.0 * noise.sigma(zp).astype(np.float64) + cfg.gate)
    free = np.bincount(bm.g[ib], weights=behind, minlength=n).astype(int)
    y, X, q, nrm = bm.y[idx], bm.X[idx], bm.q, bm.n
    sig = noise.sigma(q[:, 2]).astype(np.float64)
    r = np.sum((X - q) * nrm, axis=1)
    near = np.linalg.norm(X - q, axis=1) < 3.0 * sig + cfg.tolerance
    agree = np.bincount(gi, weights=near, minlength=n).astype(int)
    return _finish(items, terms, checked, (idx, gi, y, X, nrm, r, sig, near), (matched, agree, free), t, cfg)


def _finish(items, terms, checked, match, counts, t, cfg) -> list[IcpFit | None]:
    """The fits from the batched correspondences (the second half of ``icp._final_fit``)."""
    n = len(items)
    idx, gi, y, X, nrm, r, sig, near = match
    matched, agree, free = counts
    ng, rn, sn = gi[near], r[near], sig[near]
    gix = _group_index(ng)
    cnt = np.maximum(agree, 1)
    rmse = np.sqrt(_group_sum(rn**2, ng, n, gix) / cnt)
    rmse_sigma = np.sqrt(_group_sum((rn / sn) ** 2, ng, n, gix) / cnt)
    rs = rn / sn
    J = np.concatenate([cross(y[near], nrm[near]), nrm[near]], axis=1) / sn[:, None]
    H_depth = _group_sum(J[:, :, None] * J[:, None, :], ng, n, gix)
    H, sq, rows = H_depth.copy(), _group_sum(np.minimum(rs**2, 9.0), ng, n, gix), agree.copy()
    photos = [p for _, p in terms]
    starts = np.concatenate([[0], np.cumsum([len(m) for m, _ in checked])])
    n_photo, spread = np.zeros(n, dtype=int), np.zeros(n)
    if any(p is not None for p in photos):
        rp, Jp, gp = _photometric(PhotoStack(photos), ng, idx[near] - starts[ng], y[near], X[near], terms[0][0].K)
        gpx = _group_index(gp)
        H += _group_sum(Jp[:, :, None] * Jp[:, None, :], gp, n, gpx)
        sq += _group_sum(np.minimum(rp**2, 9.0), gp, n, gpx)
        n_photo = np.bincount(gp, minlength=n)
        rows += n_photo
        bounds = np.searchsorted(gp, np.arange(n + 1))
        for i in np.flatnonzero(np.diff(bounds)):
            spread[i] = 1.4826 * _median_exact(np.abs(rp[bounds[i] : bounds[i + 1]]))
    steps = np.array([max(it.step, 1) for it in items], dtype=np.float64)
    inflation = np.maximum(1.0, (cfg.correlation_px / steps) ** 2)
    s2 = np.maximum(sq / np.maximum(rows - 6, 1), 1.0) * inflation
    ok = (matched >= 6) & (agree >= 6)
    covs = _covariances(H[ok], s2[ok]) if ok.any() else []
    conds = (
        _conditions(
            H_depth[ok], X[near][ok[ng]], np.searchsorted(np.flatnonzero(ok), ng[ok[ng]]), t[ok], agree[ok]
        )
        if ok.any()
        else []
    )
    out: list[IcpFit | None] = []
    k = 0
    for i in range(n):
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = checked[i][1][:3, :3], checked[i][1][:3, 3]
        if matched[i] < 6:
            out.append(None)
        elif agree[i] < 6:
            out.append(
                IcpFit(
                    T,
                    int(agree[i]),
                    int(matched[i]),
                    int(agree[i]),
                    int(free[i]),
                    np.inf,
                    np.inf,
                    np.inf,
                    None,
                    0,
                )
            )
        else:
            fit = IcpFit(
                T,
                int(agree[i]),
                int(matched[i]),
                int(agree[i]),
                int(free[i]),
                float(rmse[i]),
                float(rmse_sigma[i]),
                float(conds[k]),
                covs[k],
                0,
                int(n_photo[i]),
                float(spread[i]),
            )
            out.append(fit)
            k += 1
    return out
