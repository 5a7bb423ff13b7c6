"""Many objects' dense fits at once: :func:`pal.perception.icp.icp_fit` batched over objects.

Π falls back on a dense fit for every static object whose features gave no accepted pose,
several per frame. One object at a time, each Gauss-Newton step is a few dozen small array
operations on about 100-160 model points, so the cost is the per-call overhead.
:func:`icp_fits` runs the steps of all objects together: each step associates every still
active model with its own live surface in one pass
(:func:`pal.perception.icp_batch.associate_all`), stacks the objects' whitened depth and
photometric rows, sums each object's normal equations and solves the (n, 6, 6) systems at
once. Each object keeps its own gate, convergence test, early geometric stop and failure rule
(those of ``icp._gauss_newton``), and leaves the loop when they say so; the converged poses
are then scored in one pass (:func:`pal.perception.icp_batch.scores_with_terms`). Per-point
quantities are computed elementwise exactly as one object at a time; sums over an object's
points may differ in the last bits (the order of summation), so every fit equals
:func:`icp_fit`'s to rounding.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from pal.perception.frames import RGBDFrame
from pal.perception.icp import IcpConfig, IcpFit, _checked, _terms
from pal.perception.icp_batch import (
    PhotoStack,
    ScoreItem,
    _conditions,
    _group_index,
    _group_sum,
    _photometric,
    associate_all,
    scores_with_terms,
)
from pal.perception.icp_terms import cross
from pal.perception.noise import DepthNoise

__all__ = ["icp_fits"]


def _exp_all(w: np.ndarray) -> np.ndarray:
    """Rotation matrices (n, 3, 3) of rotation vectors (n, 3) (``icp._exp`` per row)."""
    theta = np.linalg.norm(w, axis=1)
    tiny = theta < 1e-12
    k = w / np.where(tiny, 1.0, theta)[:, None]
    Kx = np.zeros((len(w), 3, 3))
    Kx[:, 0, 1], Kx[:, 0, 2], Kx[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    Kx[:, 1, 0], Kx[:, 2, 0], Kx[:, 2, 1] = k[:, 2], -k[:, 1], k[:, 0]
    out = np.eye(3) + np.sin(theta)[:, None, None] * Kx + (1.0 - np.cos(theta))[:, None, None] * (Kx @ Kx)
    out[tiny] = np.eye(3)
    return out


def _solve_all(H: np.ndarray, g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Steps ``-(H + 1e-9 tr(H) I)^-1 g`` of (m, 6, 6) systems: ((m, 6) steps, (m,) solved)."""
    A = H + 1e-9 * np.trace(H, axis1=1, axis2=2)[:, None, None] * np.eye(6)
    try:
        return -np.linalg.solve(A, g[:, :, None])[:, :, 0], np.ones(len(H), dtype=bool)
    except np.linalg.LinAlgError:
        out, ok = np.zeros((len(H), 6)), np.ones(len(H), dtype=bool)
        for i in range(len(H)):
            try:
                out[i] = -np.linalg.solve(A[i], g[i])
            except np.linalg.LinAlgError:
                ok[i] = False
        return out, ok


def _huber(rs: np.ndarray) -> np.ndarray:
    """Huber weights (k = 1.345) of whitened residuals."""
    return np.where(np.abs(rs) <= 1.345, 1.0, 1.345 / np.maximum(np.abs(rs), 1e-12))


class _Steps:
    """The Gauss-Newton state of n objects (``icp._gauss_newton``, one row per object)."""

    def __init__(self, checked: Sequence[tuple[np.ndarray, np.ndarray]], terms: list, cfg: IcpConfig) -> None:
        n = len(checked)
        self.models = [m for m, _ in checked]
        self.terms, self.cfg = terms, cfg
        self.photos = PhotoStack([p for _, p in terms])
        self.R = np.array([T[:3, :3] for _, T in checked]).reshape(n, 3, 3)
        self.t = np.array([T[:3, 3] for _, T in checked]).reshape(n, 3)
        self.active = np.ones(n, dtype=bool)
        self.failed = np.zeros(n, dtype=bool)
        self.wide = np.ones(n, dtype=bool)
        self.steps = np.zeros(n, dtype=np.int64)

    def step(self, k: int, frame: RGBDFrame, noise: DepthNoise) -> None:
        """Step ``k`` of every active object."""
        cfg = self.cfg
        act = np.flatnonzero(self.active)
        na = len(act)
        bm = associate_all(
            [self.models[i] for i in act],
            self.R[act],
            self.t[act],
            [self.terms[i][0] for i in act],
            frame,
            cfg,
        )
        gi, q, nrm = bm.gi, bm.q, bm.n
        y, X = bm.y[bm.idx], bm.X[bm.idx]
        sig = noise.sigma(q[:, 2]).astype(np.float64)
        gate = np.where(self.wide[act][gi], cfg.gate, 0.0) + 3.0 * sig + cfg.tolerance
        r = np.sum((X - q) * nrm, axis=1)
        near = np.linalg.norm(X - q, axis=1) < gate
        fail = (np.bincount(gi, minlength=na) < cfg.min_points) | (
            np.bincount(gi[near], minlength=na) < cfg.min_points
        )
        keep = near & ~fail[gi]
        ng, sn = gi[keep], sig[keep]
        rs = r[keep] / sn
        J = np.concatenate([cross(y[keep], nrm[keep]), nrm[keep]], axis=1) / sn[:, None]
        gix = _group_index(ng)
        stop = np.zeros(na, dtype=bool)
        if k == 0 and cfg.early_condition is not None:
            H_depth = _group_sum(J[:, :, None] * J[:, None, :], ng, na, gix)
            count = np.bincount(ng, minlength=na)
            cond = _conditions(H_depth, X[keep], ng, self.t[act], count)
            stop = ~fail & (cond > cfg.early_condition * cfg.max_condition)
        go = ~fail & ~stop
        w = _huber(rs) * go[ng]
        H = _group_sum(J[:, :, None] * (J * w[:, None])[:, None, :], ng, na, gix)
        g = _group_sum(J * (w * rs)[:, None], ng, na, gix)
        if self.photos.has[act[go]].any():
            sel = bm.idx[keep] - np.concatenate([[0], np.cumsum([len(self.models[i]) for i in act])])[ng]
            use = np.zeros(len(self.active), dtype=bool)
            use[act[go]] = True
            rp, Jp, gp = _photometric(self.photos, act[ng], sel, y[keep], X[keep], frame.K, use)
            gp = np.searchsorted(act, gp)
            wp = _huber(rp)
            gpx = _group_index(gp)
            H += _group_sum(Jp[:, :, None] * (Jp * wp[:, None])[:, None, :], gp, na, gpx)
            g += _group_sum(Jp * (wp * rp)[:, None], gp, na, gpx)
        self._update(act, fail, stop, go, H, g, k)

    def _update(
        self,
        act: np.ndarray,
        fail: np.ndarray,
        stop: np.ndarray,
        go: np.ndarray,
        H: np.ndarray,
        g: np.ndarray,
        k: int,
    ) -> None:
        """Apply the solved steps of the objects that go on; retire the failed, stopped and converged."""
        delta, solved = _solve_all(H[go], g[go])
        fail = fail.copy()
        fail[np.flatnonzero(go)[~solved]] = True
        self.failed[act[fail]] = True
        self.active[act[fail | stop]] = False
        moved = act[go][solved]
        delta = delta[solved]
        self.R[moved] = _exp_all(delta[:, :3]) @ self.R[moved]
        self.t[moved] = self.t[moved] + delta[:, 3:]
        self.steps[moved] = k + 1
        small = (np.linalg.norm(delta[:, :3], axis=1) < 5e-4) & (np.linalg.norm(delta[:, 3:], axis=1) < 5e-4)
        wide = self.wide[moved]
        self.active[moved[small & ~wide]] = False
        self.wide[moved] = wide & ~small & (k < self.cfg.iterations // 2)


def icp_fits(
    items: Sequence[ScoreItem],
    frame: RGBDFrame,
    noise: DepthNoise | None = None,
    config: IcpConfig | None = None,
) -> list[IcpFit | None]:
    """``[icp_fit(it.model, it.T, frame, it.mask, noise, config, it.model_gray, it.step) for it in items]`` at once.

    Args:
        items: per object its model (M, 3) object-frame points, metres; ``T`` the (4, 4) initial
            ``camera_from_object``; its live mask, grey levels (M,) or None, and grid step, pixels.
        frame: the live frame.
        noise: the depth sensor's noise model.
        config: the dense fit's parameters.

    Returns:
        Per item, its fit, or None when fewer than ``min_points`` model points ever find a
        correspondence or a step is singular (as :func:`pal.perception.icp.icp_fit`).

    Raises:
        ValueError: a model is not (M, 3), a pose not a finite (4, 4) matrix, or grey levels
            not (M,).
    """
    cfg, noise = config or IcpConfig(), noise or DepthNoise()
    checked = [_checked(it.model, it.T) for it in items]
    todo = [i for i, (m, _) in enumerate(checked) if len(m) >= cfg.min_points]
    out: list[IcpFit | None] = [None] * len(items)
    if not todo:
        return out
    terms = [_terms(frame, items[i].mask, cfg, checked[i][0], items[i].model_gray) for i in todo]
    state = _Steps([checked[i] for i in todo], terms, cfg)
    for k in range(cfg.iterations):
        if not state.active.any():
            break
        state.step(k, frame, noise)
    ok = np.flatnonzero(~state.failed)
    poses = []
    for a in ok:
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = state.R[a], state.t[a]
        poses.append((checked[todo[a]][0], T))
    fits = scores_with_terms([items[todo[a]] for a in ok], poses, [terms[a] for a in ok], frame, noise, cfg)
    for a, fit in zip(ok, fits, strict=True):
        if fit is not None:
            out[todo[a]] = dataclasses.replace(fit, iterations=int(state.steps[a]))
    return out
