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


def _ridge(g: Tensor, rhs: Tensor, lams: Tensor, eye: Tensor) -> Tensor:
    """``beta_r = (G + lam_r I)^-1 rhs`` for every penalty: ``(C, F, R, Dc)``.

    Batched Cholesky factorisations; an eigendecomposition of G (eigenvalues clamped at 0)
    when one of them fails in floating point.
    """
    c, f, dc = rhs.shape
    r = lams.shape[0]
    chol, info = torch.linalg.cholesky_ex(g[None] + lams[:, :, None, None] * eye)  # (R, C, F, F)
    if bool(info.any()):
        evals, evecs = torch.linalg.eigh(g)  # (C, F), (C, F, F)
        proj = evecs.transpose(1, 2) @ rhs  # (C, F, Dc)
        scaled = proj[:, :, None, :] / (evals.clamp_min(0)[:, :, None, None] + lams)  # (C, F, R, Dc)
        return (evecs @ scaled.reshape(c, f, -1)).reshape(c, f, r, dc)
    beta = torch.cholesky_solve(rhs.expand(r, c, f, dc), chol)  # (R, C, F, Dc)
    return beta.permute(1, 2, 0, 3)


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
        self._layouts: dict[str, tuple[Tensor, Tensor, list[int]]] = {}

    def _layout(self, child: str) -> tuple[Tensor, Tensor, list[int]]:
        """The child's evidence rows grouped by fold: ``(x rows, inverse order, fold sizes)``, cached."""
        cached = self._layouts.get(child)
        if cached is None:
            rows = self.data.rows[child]
            fold = self.fold[rows]
            order = torch.argsort(fold, stable=True)
            x = self.data.x[rows][order]
            sizes = torch.bincount(fold, minlength=self.folds).tolist()
            cached = (x, torch.argsort(order), sizes)
            self._layouts[child] = cached
        return cached

    def _design(self, x: Tensor, parent_sets: Sequence[Sequence[str]], length: float, child: str) -> Tensor:
        """``(C, n_i, 1 + F + Dc)`` rows ``[1, phi(x_P), y]`` of the candidate sets (all of one total dim).

        The constant and the child's columns ride along so that one batched Gram matrix per
        fold holds every sufficient statistic of the ridge fit.
        """
        cols = [self.data.columns(p) for p in parent_sets]
        p = len(cols[0])
        if any(len(c) != p for c in cols):
            raise ValueError("candidate parent sets in one batch must have the same total dim")
        n_i = x.shape[0]
        y = x[:, self.data.slices[child]]
        f = p + (self.features if p else 0)
        out = torch.empty(len(cols), n_i, 1 + f + y.shape[1], dtype=torch.float64)
        out[..., 0] = 1.0
        out[..., 1 + f :] = y
        if p == 0:
            return out
        idx = torch.tensor(cols)  # (C, p)
        z = x[:, idx].permute(1, 0, 2)  # (C, n_i, p)
        out[..., 1 : 1 + p] = z
        if self.features:
            w = self.omega[idx] / (length * math.sqrt(p))  # (C, p, M)
            rff = out[..., 1 + p : 1 + f]
            torch.baddbmm(self.phase, z, w, out=rff)
            rff.cos_().mul_(math.sqrt(2.0 / self.features))
        return out

    def score(self, child: str, parent_sets: Sequence[Sequence[str]]) -> Tensor:
        """S_i(P) in nats for each candidate set: ``(C,)`` float64."""
        return self.residuals(child, parent_sets)[1]

    def score_rows(self, child: str, parent_sets: Sequence[Sequence[str]]) -> tuple[Tensor, Tensor]:
        """:meth:`score` ``(C,)`` and the per-row held-out log-likelihoods ``(C, n_i)`` nats.

            l_r = -1/2 sum_d [ log(2 pi s_d^2) + u_rd^2 / s_d^2 ],   s_d^2 = max(mean_r u_rd^2, floor),

        which sum to the score unless a variance sits at the floor.
        """
        resid, score = self.residuals(child, parent_sets)
        var = resid.pow(2).mean(1, keepdim=True).clamp_min(self.floor)  # (C, 1, Dc)
        return score, -0.5 * (torch.log(2 * math.pi * var) + resid.pow(2) / var).sum(-1)

    def residuals(self, child: str, parent_sets: Sequence[Sequence[str]]) -> tuple[Tensor, Tensor]:
        """Out-of-fold residuals ``(C, n_i, dim)`` and scores ``(C,)`` of the candidate sets.

        Each fold's ridge fit comes from sufficient statistics: one batched Gram matrix of
        ``[1, Phi, y]`` per fold, a fold's training statistics are the total minus its own,
        centred in closed form, and one eigendecomposition per fold solves the ridge systems
        of every penalty.
        """
        if not parent_sets:
            raise ValueError("give at least one candidate parent set")
        self.calls += len(parent_sets)
        x, inverse, sizes = self._layout(child)
        if min(sizes) < 1 or x.shape[0] - max(sizes) < 2:
            small = next(k for k, s in enumerate(sizes) if s < 1 or x.shape[0] - s < 2)
            raise ValueError(f"fold {small} of {child!r} is too small; give more rows or fewer folds")
        y = x[:, self.data.slices[child]]  # (n_i, Dc)
        c, n_i, dc = len(parent_sets), x.shape[0], y.shape[1]
        bounds = [0, *torch.tensor(sizes).cumsum(0).tolist()]
        blocks = [slice(bounds[k], bounds[k + 1]) for k in range(self.folds)]
        lams = torch.tensor(self.ridge, dtype=torch.float64)[:, None]  # (R, 1)
        best_err = torch.full((c,), math.inf, dtype=torch.float64)
        best = torch.empty(c, n_i, dc, dtype=torch.float64)
        lengths = self.length if self.data.columns(parent_sets[0]) and self.features else self.length[:1]
        for length in lengths:
            aug = self._design(x, parent_sets, length, child)  # (C, n_i, 1 + F + Dc)
            f = aug.shape[-1] - 1 - dc
            phi = aug[..., 1 : 1 + f]
            resid = torch.empty(len(self.ridge), c, n_i, dc, dtype=torch.float64)
            eye = torch.eye(f, dtype=torch.float64)
            gram = [aug[:, b].transpose(1, 2) @ aug[:, b] for b in blocks]  # (C, A, A) sums per fold
            total = sum(gram)
            for k, b in enumerate(blocks):
                stats = total - gram[k]  # training rows of fold k: [[n, s^T, t^T], [s, S, T], ...]
                n_tr = n_i - sizes[k]
                y_mean = stats[:, 0, 1 + f :] / n_tr  # (C, Dc)
                if not f:
                    resid[:, :, b] = y[b] - y_mean[:, None, :]
                    continue
                m = stats[:, 0, 1 : 1 + f] / n_tr  # (C, F)
                g = stats[:, 1 : 1 + f, 1 : 1 + f] - n_tr * m[:, :, None] * m[:, None, :]
                rhs = stats[:, 1 : 1 + f, 1 + f :] - n_tr * m[:, :, None] * y_mean[:, None, :]  # (C, F, Dc)
                beta = _ridge(g, rhs, lams, eye)  # (C, F, R, Dc)
                offset = y_mean[:, None, :] - torch.einsum("cf,cfrd->crd", m, beta)  # (C, R, Dc)
                fitted = (phi[:, b] @ beta.reshape(c, f, -1)).reshape(c, -1, len(self.ridge), dc)
                resid[:, :, b] = (y[b][None, :, None, :] - offset[:, None] - fitted).permute(2, 0, 1, 3)
            err, pick = resid.pow(2).mean((2, 3)).min(0)  # (C,): best ridge per candidate
            if len(lengths) == 1:  # nothing to compare with
                best = resid[pick, torch.arange(c)]
                break
            better = err < best_err
            best_err = torch.where(better, err, best_err)
            best[better] = resid[pick, torch.arange(c)][better]
        resid = best[:, inverse]
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

    def score_rows(self, child: str, parent_sets: Sequence[Sequence[str]]) -> tuple[Tensor, Tensor]:
        """Mean score ``(C,)`` and mean per-row log-likelihoods ``(C, n_i)`` over the repeats."""
        pairs = [s.score_rows(child, parent_sets) for s in self.scorers]
        return torch.stack([p[0] for p in pairs]).mean(0), torch.stack([p[1] for p in pairs]).mean(0)
