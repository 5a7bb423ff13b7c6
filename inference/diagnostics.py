"""How well a posterior fits: effective sample size, Pareto-k of importance weights, grid edge mass.

For unit n with log importance weights ``lw_s = log p(x_n, z_s) - log q(z_s)``, s = 1 .. S:

    ESS_n  = (sum_s w_s)^2 / sum_s w_s^2
    k_n    = the shape of a generalized Pareto fitted to the M = min(S / 5, 3 sqrt(S)) largest
             weights above the next one (Vehtari et al. 2024, PSIS; Zhang and Stephens 2009
             estimator with the weakly informative prior of the PSIS paper)

``k < 0.5``: the importance estimates are reliable; ``0.5 <= k < 0.7``: usable;
``k >= 0.7``: the proposal (the guide) misses mass of the posterior, e.g. a mode.
For the exact grid, ``edge_mass`` is the posterior mass in the outermost cells of the grid:
more than 1e-3 says that the grid was too narrow.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import torch
from torch import Tensor

__all__ = ["PARETO_K_THRESHOLD", "Diagnostics", "PoorPosteriorWarning", "ess", "pareto_k"]

#: Above this Pareto-k the posterior approximation is flagged (Vehtari et al.).
PARETO_K_THRESHOLD = 0.7
#: Above this share of the mass on the outermost grid cells the grid is flagged.
EDGE_MASS_THRESHOLD = 1e-3


class PoorPosteriorWarning(UserWarning):
    """The chosen posterior approximation fits some units poorly (see :class:`Diagnostics`)."""


def ess(log_weights: Tensor) -> Tensor:
    """Effective sample size per unit: ``(S, N) -> (N,)``."""
    w = torch.softmax(log_weights, 0)
    return 1.0 / (w**2).sum(0)


def _gpd_shape(x: Tensor) -> Tensor:
    """Generalized Pareto shape k of exceedances ``x`` (sorted ascending along the last axis): ``(U, M) -> (U,)``."""
    m = x.shape[-1]
    grid = 30 + int(math.sqrt(m))
    j = torch.arange(1, grid + 1, dtype=x.dtype)
    quartile = x[..., max(int(m / 4 + 0.5) - 1, 0)].clamp_min(1e-300)
    top = x[..., -1].clamp_min(1e-300)
    b = 1 / top[..., None] + (1 - torch.sqrt(grid / (j - 0.5))) / (3 * quartile[..., None])  # (U, G)
    k = torch.log1p(-b[..., None] * x[..., None, :]).mean(-1)  # (U, G)
    lik = m * (torch.log(-b / k) - k - 1)
    weights = torch.softmax(lik, -1)
    b_hat = (b * weights).sum(-1)
    k_hat = torch.log1p(-b_hat[..., None] * x).mean(-1)
    return (m * k_hat + 10 * 0.5) / (m + 10)  # prior towards 0.5 (PSIS, Appendix C)


def pareto_k(log_weights: Tensor) -> Tensor:
    """PSIS Pareto-k per unit: ``(S, N)`` log weights -> ``(N,)`` (NaN when S < 10)."""
    s = log_weights.shape[0]
    if s < 10:
        return torch.full(log_weights.shape[1:], math.nan, dtype=log_weights.dtype)
    m = max(int(min(0.2 * s, 3 * math.sqrt(s))), 5)
    lw = log_weights.double().T  # (N, S)
    top, _ = torch.topk(lw, m + 1, dim=-1, sorted=True)  # descending
    big = top[..., :1]
    tail = torch.exp(top[..., :m] - big) - torch.exp(top[..., m : m + 1] - big)
    tail = tail.flip(-1).clamp_min(0)  # ascending exceedances
    k = _gpd_shape(tail)
    degenerate = tail[..., -1] <= 0  # all tail weights equal: no tail at all
    return torch.where(degenerate, torch.full_like(k, -math.inf), k).to(log_weights.dtype)


@dataclass(frozen=True)
class Diagnostics:
    """Per-unit fit diagnostics of a state posterior.

    Attributes:
        method: the posterior method that produced them.
        pareto_k: ``(N,)`` PSIS Pareto-k of the importance weights (of the guide as a
            proposal for SVI guides, of the prior for importance sampling); None for the grid.
        ess: ``(N,)`` effective sample size of those weights (of the grid cells for the grid).
        edge_mass: ``(N,)`` posterior mass on the outermost grid cells (grid only).
        flagged: indices of the units over the threshold.
        message: one line saying what was found.
    """

    method: str
    pareto_k: Tensor | None = None
    ess: Tensor | None = None
    edge_mass: Tensor | None = None
    flagged: tuple[int, ...] = ()
    message: str = ""
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        """True when no unit is flagged."""
        return not self.flagged

    def to_dict(self) -> dict[str, Any]:
        """JSON-compatible summary (worst and median values, flagged units)."""

        def summary(t: Tensor | None) -> dict[str, float] | None:
            if t is None:
                return None
            finite = t[torch.isfinite(t)]
            if finite.numel() == 0:
                return {"max": math.nan, "median": math.nan, "min": math.nan}
            return {
                "max": float(finite.max()),
                "median": float(finite.median()),
                "min": float(finite.min()),
            }

        return {
            "method": self.method,
            "pareto_k": summary(self.pareto_k),
            "ess": summary(self.ess),
            "edge_mass": summary(self.edge_mass),
            "flagged": list(self.flagged),
            "ok": self.ok,
            "message": self.message,
            **self.extra,
        }


def from_weights(method: str, log_weights: Tensor, what: str) -> Diagnostics:
    """Diagnostics of ``(S, N)`` log importance weights; ``what`` names the proposal."""
    k = pareto_k(log_weights)
    e = ess(log_weights)
    flagged = tuple(int(i) for i in torch.nonzero(k > PARETO_K_THRESHOLD).flatten())
    if flagged:
        message = (
            f"{method}: Pareto-k > {PARETO_K_THRESHOLD} on {len(flagged)} of {k.numel()} units (worst "
            f"{float(k[torch.isfinite(k)].max()):.2f}): {what} misses posterior mass there, e.g. a mode; "
            "try guide='grid' (low-dimensional latents), 'importance' or 'flow'"
        )
    else:
        message = f"{method}: Pareto-k <= {PARETO_K_THRESHOLD} on every unit"
    return Diagnostics(method, pareto_k=k, ess=e, flagged=flagged, message=message)
