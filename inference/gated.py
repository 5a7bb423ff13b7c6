"""Group-lasso-gated MLP parent selection (sparsification step of structure learning).

Every child X_i gets a one-hidden-layer MLP over *all* its candidate parents,

    f_i(x) = W2_i tanh(W1_i (m_i * x) + b1_i) + b2_i,

where ``m_i`` masks non-candidates. The first-layer columns of parent j form a group
g_ij = W1_i[:, cols(j)], and training minimises

    sum_i mean_{rows r evident about X_i} ||x_ri - f_i(x_r)||^2 / dim_i  +  lambda * sum_ij ||g_ij||_2

with Adam steps followed by the group soft-threshold g <- g * max(0, 1 - lr * lambda / ||g||),
which sets whole groups exactly to zero. Over a decreasing penalty path (warm-started), each
child keeps the parent set (non-zero groups) of the penalty whose held-out Gaussian
log-likelihood is best. All children train in one batched tensor program.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor

from inference.admissible import StructureData
from models.checks import check_float, check_int, check_mapping, check_seed, describe

__all__ = ["select_parents"]


def select_parents(
    data: StructureData,
    candidates: Mapping[str, Sequence[str]],
    *,
    penalties: Sequence[float] = (0.3, 0.1, 0.03, 0.01),
    hidden: int = 16,
    steps: int = 300,
    lr: float = 0.01,
    val_fraction: float = 0.2,
    seed: int = 0,
) -> dict[str, tuple[str, ...]]:
    """Select parents among ``candidates`` (child -> names) with gated MLPs.

    Args:
        data: standardised data and evidence masks.
        candidates: child -> candidate parents (must be acyclic-consistent, e.g. the
            predecessors in a topological order); children without candidates get none.
        penalties: the lambda path, in decreasing order.
        hidden: hidden units per child.
        steps: Adam steps per penalty.
        lr: Adam learning rate (also the proximal step).
        val_fraction: held-out share of rows for the selection.
        seed: seeds the split and the initial weights.

    Returns:
        child -> selected parents (declaration order).
    """
    penalties = _check_penalties(penalties)
    hidden = check_int("hidden", hidden, minimum=1)
    steps = check_int("steps", steps, minimum=1)
    lr = check_float("lr", lr, minimum=0.0, min_open=True)
    val_fraction = check_float(
        "val_fraction", val_fraction, minimum=0.0, maximum=1.0, min_open=True, max_open=True
    )
    seed = check_seed("seed", seed)
    candidates = check_mapping("candidates", candidates)
    names = data.names
    children = [c for c in names if candidates.get(c)]
    if not children:
        return {c: () for c in names}
    net = _GatedNet.build(data, candidates, children, hidden, val_fraction, seed)
    chosen = _penalty_path(net, penalties, steps, lr)
    order = {nm: i for i, nm in enumerate(names)}
    return {c: tuple(sorted(chosen.get(c, ()), key=order.__getitem__)) for c in names}


def _check_penalties(penalties: Any) -> list[float]:
    if isinstance(penalties, (str, bytes)) or not isinstance(penalties, Sequence) or not penalties:
        raise ValueError(f"penalties must be a non-empty sequence of numbers > 0, got {describe(penalties)}")
    penalties = [
        check_float(f"penalties[{k}]", p, minimum=0.0, min_open=True) for k, p in enumerate(penalties)
    ]
    if penalties != sorted(penalties, reverse=True):
        raise ValueError(f"penalties must be positive and decreasing, got {list(penalties)}")
    return penalties


@dataclass
class _GatedNet:
    """The batched gated MLPs of every child, their masks, groups and the validation split."""

    children: list[str]
    x: Tensor  # (n, D) float64
    in_mask: Tensor  # (V, D): the candidate columns of each child
    out_mask: Tensor  # (V, D): each child's own columns, weighted 1 / dim
    rows: Tensor  # (n, V): rows evident about each child
    val: Tensor  # (n,) bool: held-out rows
    weights: list[Tensor]  # w1 (V, H, D), b1 (V, H), w2 (V, H, D), b2 (V, D)
    groups: dict[str, list[tuple[str, list[int]]]]  # child -> (candidate, its columns)
    col_group: Tensor  # (D, variables): column -> its variable

    @classmethod
    def build(
        cls,
        data: StructureData,
        candidates: Mapping[str, Sequence[str]],
        children: list[str],
        hidden: int,
        val_fraction: float,
        seed: int,
    ) -> _GatedNet:
        gen = torch.Generator().manual_seed(seed)
        names = data.names
        n, d_in = data.x.shape
        v = len(children)
        in_mask = torch.zeros(v, d_in, dtype=torch.float64)
        out_mask = torch.zeros(v, d_in, dtype=torch.float64)
        rows = torch.stack([data.rows[c] for c in children], 1).double()  # (n, V)
        for k, c in enumerate(children):
            in_mask[k, data.columns(candidates[c])] = 1.0
            out_mask[k, data.columns([c])] = 1.0 / len(data.columns([c]))
        perm = torch.randperm(n, generator=gen)
        val = torch.zeros(n, dtype=torch.bool)
        val[perm[: max(1, round(val_fraction * n))]] = True
        w1 = (
            torch.randn(v, hidden, d_in, generator=gen, dtype=torch.float64) * 0.3 * in_mask[:, None]
        ).requires_grad_()
        b1 = torch.zeros(v, hidden, dtype=torch.float64, requires_grad=True)
        w2 = (
            torch.randn(v, hidden, d_in, generator=gen, dtype=torch.float64) * 0.3 / math.sqrt(hidden)
        ).requires_grad_()
        b2 = torch.zeros(v, d_in, dtype=torch.float64, requires_grad=True)
        groups = {c: [(p, data.columns([p])) for p in candidates[c]] for c in children}
        col_group = torch.zeros(d_in, len(names), dtype=torch.float64)
        for j, nm in enumerate(names):
            col_group[data.columns([nm]), j] = 1.0
        return cls(
            children, data.x.double(), in_mask, out_mask, rows, val, [w1, b1, w2, b2], groups, col_group
        )

    def sq_error(self, idx: Tensor) -> Tensor:
        """Weighted squared error ``(n_idx, V)`` of every child on the rows ``idx``."""
        w1, b1, w2, b2 = self.weights
        x = self.x[idx]
        h = torch.tanh(torch.einsum("nd,vhd->nvh", x, w1 * self.in_mask[:, None]) + b1)
        out = torch.einsum("nvh,vhd->nvd", h, w2) + b2
        return ((out - x[:, None, :]) ** 2 * self.out_mask).sum(-1)


def _penalty_path(
    net: _GatedNet, penalties: Sequence[float], steps: int, lr: float
) -> dict[str, tuple[str, ...]]:
    """Proximal Adam over the penalty path; each child's parents at its best held-out likelihood."""
    w1, val, col_group = net.weights[0], net.val, net.col_group
    train_rows, val_rows = net.rows[~val], net.rows[val]
    optim = torch.optim.Adam(net.weights, lr=lr)
    best = torch.full((len(net.children),), math.inf, dtype=torch.float64)
    chosen = {c: tuple(p for p, _ in net.groups[c]) for c in net.children}
    for lam in penalties:
        for _ in range(steps):
            optim.zero_grad()
            err = net.sq_error(~val)
            loss = ((err * train_rows).sum(0) / train_rows.sum(0).clamp_min(1)).sum()
            loss.backward()
            optim.step()
            with torch.no_grad():
                norms = ((w1**2).sum(1) @ col_group).sqrt()  # (V, variables)
                shrink = torch.clamp(1 - lr * lam / norms.clamp_min(1e-12), min=0.0) @ col_group.T  # (V, D)
                w1.mul_(shrink[:, None, :])
        with torch.no_grad():
            mse_tr = (net.sq_error(~val) * train_rows).sum(0) / train_rows.sum(0).clamp_min(1)
            mse_val = (net.sq_error(val) * val_rows).sum(0) / val_rows.sum(0).clamp_min(1)
            var = mse_tr.clamp_min(1e-12)
            nll = 0.5 * torch.log(2 * math.pi * var) + mse_val / (2 * var)
            for k, c in enumerate(net.children):
                if nll[k] < best[k]:
                    best[k] = nll[k]
                    chosen[c] = tuple(p for p, cols in net.groups[c] if float(w1[k][:, cols].norm()) > 0)
    return chosen
