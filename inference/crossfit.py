"""Held-out local log-likelihoods for candidate parent sets (structure learning's score).

For a child X_i and a candidate parent set P the local model is the additive-noise
regression

    X_i = g_P(x_P) + U_i,   U_i ~ N(0, diag(s_i^2)),
    g_P(z) = c + B z + C sqrt(2/M) cos(Omega_P z / (l sqrt(|P|)) + b),

a linear term plus M random Fourier features of an RBF kernel of length l (in standard
deviations of the standardised inputs), fitted by ridge regression. The length l and the
ridge penalty are picked per candidate from small grids by the pooled out-of-fold error
(one choice for all folds). The score is the
K-fold cross-fitted Gaussian log-likelihood over the rows that are evidence about f_i (not
intervened on X_i):

    S_i(P) = -(n_i / 2) * sum_k [ log(2 pi s_ik^2) + 1 ],
    s_ik^2 = max(mean out-of-fold residual^2, floor).

The floor (in units of the standardised variance) is a measurement resolution: when a
variable is an exact function of others (e.g. q = q_prev + dq in float32 data), residuals
at rounding level would otherwise turn fits of rounding noise into large likelihood gains.

Because every row is predicted by a model that did not see it, adding an irrelevant parent
does not raise S_i in expectation, so score differences are held-out log-likelihood ratios
in nats. The score is invariant to rescaling any column.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import Tensor

from inference.admissible import StructureData
from models.checks import check_float, check_int, check_seed, describe

__all__ = ["CrossFitScorer", "RepeatedScorer"]


def _grid(name: str, value: float | Sequence[float]) -> tuple[float, ...]:
    """A non-empty tuple of finite values > 0 from a number or a sequence of numbers."""
    if (
        isinstance(value, (str, bytes))
        or not isinstance(value, (Sequence, int, float))
        or isinstance(value, bool)
    ):
        raise ValueError(
            f"{name} must be a number > 0 or a non-empty sequence of such, got {describe(value)}"
        )
    if not isinstance(value, Sequence):
        return (check_float(name, value, minimum=0.0, min_open=True),)
    if not value:
        raise ValueError(f"{name} is an empty sequence; expected at least one value > 0")
    return tuple(check_float(f"{name}[{k}]", v, minimum=0.0, min_open=True) for k, v in enumerate(value))


class CrossFitScorer:
    """Batched cross-fitted random-feature ridge scores.

    Args:
        data: the standardised data and evidence masks.
        features: random Fourier features M (0: linear regression only).
        ridge: ridge penalties on the feature weights to choose from (a float: just that one).
        folds: K >= 2.
        length: RBF length scale(s) l per sqrt(|P|) to choose from, in standard deviations.
        floor: smallest residual variance, in standardised units (sd floor 1e-3 x sd).
        seed: seeds the folds and the random features.
    """

    def __init__(
        self,
        data: StructureData,
        *,
        features: int = 64,
        ridge: float | Sequence[float] = (1e-3, 1e-2, 1e-1, 1.0),
        folds: int = 2,
        length: float | Sequence[float] = (0.7, 2.0),
        floor: float = 1e-6,
        seed: int = 0,
    ) -> None:
        features = check_int("features", features, minimum=0)
        ridge = _grid("ridge", ridge)
        folds = check_int("folds", folds, minimum=2)
        length = _grid("length", length)
        floor = check_float("floor", floor, minimum=0.0, min_open=True)
        seed = check_seed("seed", seed)
        self.data, self.features, self.ridge, self.folds, self.length = data, features, ridge, folds, length
        self.floor = float(floor)
        gen = torch.Generator().manual_seed(seed)
        n, d = data.x.shape
        self.fold = torch.randperm(n, generator=gen) % folds
        scale = torch.tensor(
            [length[m * len(length) // max(features, 1)] for m in range(features)], dtype=torch.float64
        )
        self.omega = torch.randn(d, features, generator=gen, dtype=torch.float64) / scale
        self.phase = 2 * math.pi * torch.rand(features, generator=gen, dtype=torch.float64)
        self.calls = 0

    def _design(self, rows: Tensor, parent_sets: Sequence[Sequence[str]], length: float) -> Tensor:
        """``(C, n_i, F)`` features of the candidate sets (all of the same total dim)."""
        cols = [self.data.columns(p) for p in parent_sets]
        p = len(cols[0])
        if any(len(c) != p for c in cols):
            raise ValueError("candidate parent sets in one batch must have the same total dim")
        n_i = int(rows.sum())
        if p == 0:
            return torch.zeros(len(cols), n_i, 0, dtype=torch.float64)
        idx = torch.tensor(cols)  # (C, p)
        z = self.data.x[rows][:, idx].permute(1, 0, 2)  # (C, n_i, p)
        if self.features == 0:
            return z
        w = self.omega[idx] / (length * math.sqrt(p))  # (C, p, M)
        rff = math.sqrt(2.0 / self.features) * torch.cos(z @ w + self.phase)
        return torch.cat([z, rff], -1)

    def score(self, child: str, parent_sets: Sequence[Sequence[str]]) -> Tensor:
        """S_i(P) in nats for each candidate set: ``(C,)`` float64."""
        return self.residuals(child, parent_sets)[1]

    def residuals(self, child: str, parent_sets: Sequence[Sequence[str]]) -> tuple[Tensor, Tensor]:
        """Out-of-fold residuals ``(C, n_i, dim)`` and scores ``(C,)`` of the candidate sets."""
        if not parent_sets:
            raise ValueError("give at least one candidate parent set")
        self.calls += len(parent_sets)
        rows = self.data.rows[child]
        y = self.data.x[rows][:, self.data.slices[child]]  # (n_i, Dc)
        fold = self.fold[rows]
        c, n_i = len(parent_sets), int(rows.sum())
        lams = torch.tensor(self.ridge, dtype=torch.float64)
        best_err = torch.full((c,), math.inf, dtype=torch.float64)
        best = torch.empty(c, n_i, y.shape[1], dtype=torch.float64)
        for length in self.length if self.data.columns(parent_sets[0]) and self.features else self.length[:1]:
            phi = self._design(rows, parent_sets, length)  # (C, n_i, F)
            resid = torch.empty(len(lams), c, n_i, y.shape[1], dtype=torch.float64)
            for k in range(self.folds):
                tr, te = fold != k, fold == k
                if int(tr.sum()) < 2 or int(te.sum()) < 1:
                    raise ValueError(f"fold {k} of {child!r} is too small; give more rows or fewer folds")
                y_mean = y[tr].mean(0)
                if phi.shape[-1] == 0:
                    resid[:, :, te] = y[te] - y_mean
                    continue
                ptr, pte = phi[:, tr], phi[:, te]
                p_mean = ptr.mean(1, keepdim=True)
                ptr, pte = ptr - p_mean, pte - p_mean
                evals, evecs = torch.linalg.eigh(ptr.transpose(1, 2) @ ptr)  # (C, F), (C, F, F)
                proj = evecs.transpose(1, 2) @ (ptr.transpose(1, 2) @ (y[tr] - y_mean))  # (C, F, Dc)
                test = pte @ evecs  # (C, n_te, F)
                for r, lam in enumerate(lams):
                    beta = proj / (evals.clamp_min(0) + lam)[..., None]
                    resid[r, :, te] = (y[te] - y_mean) - test @ beta
            err, pick = resid.pow(2).mean((2, 3)).min(0)  # (C,): best ridge per candidate
            better = err < best_err
            best_err = torch.where(better, err, best_err)
            best[better] = resid[pick, torch.arange(c)][better]
        resid = best
        var = resid.pow(2).mean(1).clamp_min(self.floor)  # (C, Dc)
        score = -0.5 * n_i * (torch.log(2 * math.pi * var) + 1.0).sum(-1)
        return resid, score


class RepeatedScorer:
    """The mean of S_i(P) over ``repeats`` scorers with different folds and random features.

    Repeated cross-fitting lowers the variance that one fold split and one feature draw
    put into score differences (and so into the search's early decisions).

    Args:
        data: as for :class:`CrossFitScorer`.
        repeats: number of scorers (seeds ``seed, seed + 1, ...``).
        **kwargs: passed to each :class:`CrossFitScorer`.
    """

    def __init__(self, data: StructureData, *, repeats: int = 1, seed: int = 0, **kwargs: object) -> None:
        repeats = check_int("repeats", repeats, minimum=1)
        self.data = data
        self.scorers = [CrossFitScorer(data, seed=seed + r, **kwargs) for r in range(repeats)]  # type: ignore[arg-type]

    @property
    def calls(self) -> int:
        """Parent sets scored so far by the first scorer (each repeat scores the same sets)."""
        return self.scorers[0].calls

    def score(self, child: str, parent_sets: Sequence[Sequence[str]]) -> Tensor:
        """Mean S_i(P) over the repeats, ``(C,)`` nats."""
        return torch.stack([s.score(child, parent_sets) for s in self.scorers]).mean(0)
