"""Active experimental design for mechanisms: ensemble disagreement (thesis §4.3.2, regime 3).

K world models on one graph, trained on bootstrap resamples of the agent's data, stand in
for the posterior over the mechanisms. For a candidate intervention ``do(A = a)`` in state s
the expected information about the mechanisms of the target variables is scored, as for
Gaussian predictive models with noise sigma_i, by

    I(a; s) = sum_{i in targets} sum_k 0.5 * log(1 + Var_m[Phi_ik^(m)(s, a)] / sigma_ik^2),

the mutual information between the outcome and the member index when the members'
predictions are the posterior samples (BALD for regression). :meth:`Ensemble.choose` picks
per state the candidate with the largest I. It is an alternative to curiosity targets
(:class:`inference.CuriositySampler`): curiosity seeks rarely seen outcomes, this seeks
outcomes the model cannot yet predict.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import torch
from torch import Tensor

from inference.fit import FIT_KWARGS, fit
from models.checks import (
    check_callable,
    check_float,
    check_int,
    check_keywords,
    check_names,
    check_seed,
    describe,
)
from models.world import WorldModel, as_values

__all__ = ["Ensemble"]


class Ensemble:
    """K world models on the same graph.

    Args:
        members: the models (at least 2), all on one graph.
    """

    def __init__(self, members: Sequence[WorldModel]) -> None:
        if isinstance(members, (str, bytes)) or not isinstance(members, Sequence):
            raise ValueError(f"members must be a sequence of WorldModel, got {describe(members)}")
        members = list(members)
        for k, m in enumerate(members):
            if not isinstance(m, WorldModel):
                raise ValueError(f"ensemble member {k} must be a WorldModel, got {describe(m)}")
        if len(members) < 2:
            raise ValueError(f"an ensemble needs at least 2 members, got {len(members)}")
        fp = members[0].graph.fingerprint()
        if any(m.graph.fingerprint() != fp for m in members):
            raise ValueError("ensemble members must share one graph")
        self.members = members
        self.graph = members[0].graph

    @classmethod
    def create(cls, make: Callable[[int], WorldModel], k: int = 5, seed: int = 0) -> Ensemble:
        """An ensemble of ``k`` members ``make(seed + m)``.

        The factory seeds each member's weights, e.g. ``lambda s: WorldModel(graph, seed=s)``.
        """
        check_callable("make", make)
        k = check_int("k", k, minimum=2)
        seed = check_seed("seed", seed)
        return cls([make(seed + m) for m in range(k)])

    def fit(self, data: Mapping[str, Any], *, seed: int = 0, **fit_kwargs: Any) -> None:
        """Train every member (in place, warm) on its own bootstrap resample of ``data``.

        Args:
            data: name -> ``(N, dim)`` columns (see :func:`inference.fit`).
            seed: seeds the resamples (local generator) and member m's fit with ``seed + m``.
            **fit_kwargs: passed to :func:`inference.fit` (not ``seed``).
        """
        seed = check_seed("seed", seed)
        fit_kwargs = check_keywords("fit_kwargs", fit_kwargs, [k for k in FIT_KWARGS if k != "seed"])
        cols, n = as_values(self.graph, data, dtype=self.members[0].dtype)
        if n is None or n < 2:
            raise ValueError(f"ensemble fit needs at least 2 rows, got {n}")
        gen = torch.Generator().manual_seed(seed)
        for m, model in enumerate(self.members):
            idx = torch.randint(n, (n,), generator=gen)
            fit(model, {k: v[idx] for k, v in cols.items()}, seed=seed + m, **fit_kwargs)

    def predict(self, values: Mapping[str, Any]) -> dict[str, Tensor]:
        """Ensemble-mean forward query (expected residuals): name -> ``(N, dim)``."""
        preds = [m.predict(values) for m in self.members]
        return {k: torch.stack([p[k] for p in preds]).mean(0) for k in preds[0]}

    def information(self, values: Mapping[str, Any], targets: Sequence[str]) -> Tensor:
        """I(a; s) per unit, ``(N,)`` nats (see the module docstring).

        Args:
            values: name -> ``(N, dim)`` for every root (actions within bounds).
            targets: non-root variables whose mechanisms the outcome should inform.
        """
        targets = check_names("targets", targets, allow_empty=False)
        for t in targets:
            self.graph.check_name(t, what="target")
            if self.graph.is_root(t):
                raise ValueError(f"target {t!r} is a root; its value is given, not predicted")
        preds = [m.predict(values) for m in self.members]
        total = 0.0
        for t in targets:
            stack = torch.stack([p[t] for p in preds])  # (K, N, dim)
            sigma2 = torch.stack([m.sigma(t).detach() for m in self.members]).pow(2).mean(0)
            total = total + 0.5 * torch.log1p(stack.var(0, unbiased=False) / sigma2).sum(-1)
        return total  # type: ignore[return-value]

    def choose(
        self,
        state: Mapping[str, Any],
        candidates: Mapping[str, Any],
        targets: Sequence[str],
        spread: float | None = None,
    ) -> tuple[dict[str, Tensor], Tensor]:
        """Pick per unit the candidate intervention with the largest information.

        Args:
            state: name -> ``(N, dim)`` values of the other roots.
            candidates: action name -> ``(N, C, dim)`` candidate values (same C for all).
            targets: variables whose mechanisms the experiment should inform.
            spread: None for the argmax per unit; a length (in sd of the candidate points)
                for a diverse batch, where each choice damps the information of nearby
                points for the units after it (units in a batch would otherwise crowd
                into the same region).

        Returns:
            ``(chosen, info)``: action name -> ``(N, dim)``, and ``(N,)`` the chosen information.
        """
        if spread is not None:
            spread = check_float("spread", spread, minimum=0.0, min_open=True)
        dtype = self.members[0].dtype
        given, n = as_values(self.graph, state, what="state", dtype=dtype)
        cands, n = as_values(self.graph, candidates, n=n, what="candidates", extra_dims=1, dtype=dtype)
        if not cands:
            raise ValueError("candidates is empty; give (N, C, dim) values for at least one action")
        c = {v.shape[1] for v in cands.values()}
        if len(c) != 1:
            raise ValueError(f"candidates have different counts {sorted(c)}; expected one C")
        (c,) = c
        flat = {k: v.repeat_interleave(c, 0) for k, v in given.items()}
        flat |= {k: v.reshape(-1, v.shape[-1]) for k, v in cands.items()}
        info = self.information(flat, targets).reshape(-1, c)  # (N, C)
        rows = torch.arange(info.shape[0])
        if spread is None:
            best = info.argmax(1)
            return {k: v[rows, best] for k, v in cands.items()}, info[rows, best]
        # batch diversity: units choose in turn, and each choice damps the information of
        # nearby (state, action) points of later units by 1 - exp(-d^2 / (2 spread^2)),
        # d measured in standard deviations of the candidate points
        z = torch.cat([flat[k] for k in sorted(flat)], -1).reshape(info.shape[0], c, -1)
        z = (z - z.reshape(-1, z.shape[-1]).mean(0)) / z.reshape(-1, z.shape[-1]).std(0).clamp_min(1e-12)
        damp = torch.ones_like(info)
        best = torch.empty(info.shape[0], dtype=torch.long)
        for u in range(info.shape[0]):
            best[u] = (info[u] * damp[u]).argmax()
            d2 = (z - z[u, best[u]]).pow(2).sum(-1)
            damp = damp * (1 - torch.exp(-d2 / (2 * spread**2)))
        return {k: v[rows, best] for k, v in cands.items()}, info[rows, best]
