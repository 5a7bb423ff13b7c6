"""Meta-learning: structural revision of the world model under persistent residuals (thesis §4.3.6).

A :class:`ResidualMonitor` (:mod:`inference.residual_monitor`) keeps, per variable X_i, the
windowed mean of Eq. 4.50,

    m_i(t) = (1 / W) * sum_{tau = t-W}^{t-1} ||u_i(tau)||^2,   u_i = (x_i - f_i(pa_i)) / s_i,

with s_i a reference scale: a per-variable tolerance when given (the error the agent can
accept), else sigma_i of the model when the monitor was made. A variable is *flagged* when
m_i exceeds ``threshold`` x dim_i after ``patience`` consecutive updates (each after a refit).

:func:`revise` then proposes and tests, for every flagged X_i, the revisions

- ``add_parent``: pa_i + j for every admissible, acyclic j;
- ``capacity``: an MLP with twice the hidden width and one more layer;
- ``split``: a regime split f_i = f_i^a if x_s < c else f_i^b, on the parent component x_s
  whose median split lowers the residual most (c = that median),

each fitted (Eq. 4.33) on a training part of the recent data and scored by the Gaussian
log-likelihood of X_i on the held-out part. A revision is kept only if it beats the current
mechanism, refitted the same way, by more than ``min_gain`` nats. Every test is logged as a
:class:`Revision` with its evidence.
"""

from __future__ import annotations

import copy
import dataclasses
import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import torch
from torch import Tensor, nn

from inference.admissible import admissible_parents
from inference.fit import FIT_KWARGS, FitSchedule, fit
from inference.residual_monitor import ResidualMonitor
from models.checks import (
    check_float,
    check_hidden,
    check_int,
    check_keywords,
    check_names,
    check_seed,
    describe,
)
from models.graph import CausalGraph
from models.mechanisms import Mechanism, MLPMechanism
from models.world import WorldModel, as_values, require_world_model

#: The revision kinds :func:`revise` can try.
KINDS = ("add_parent", "capacity", "split")

__all__ = ["ResidualMonitor", "Revision", "SplitMechanism", "revise"]

log = logging.getLogger(__name__)


class SplitMechanism(Mechanism):
    """A regime split f(z) = f_a(z) if z_s < c else f_b(z) (z: the concatenated parents).

    Not serialisable by :mod:`models.io` (only MLP and linear mechanisms are).
    """

    kind = "split"

    def __init__(self, low: Mechanism, high: Mechanism, component: int, cut: float) -> None:
        for what, mech in (("low", low), ("high", high)):
            if not isinstance(mech, Mechanism):
                raise ValueError(f"{what} regime must be a Mechanism, got {describe(mech)}")
        super().__init__(low.in_dim, low.out_dim)
        if (high.in_dim, high.out_dim) != (low.in_dim, low.out_dim):
            raise ValueError("both regimes of a split need the same input and output dims")
        component = check_int("component", component, minimum=0)
        if not component < low.in_dim:
            raise ValueError(f"split component {component} out of range for in_dim {low.in_dim}")
        cut = check_float("cut", cut)
        self.low, self.high, self.component, self.cut = low, high, component, cut
        self.log_sigma = nn.Parameter(torch.maximum(low.log_sigma, high.log_sigma).detach().clone())

    def forward(self, parents: Tensor) -> Tensor:
        """``(..., out_dim)`` output of the regime selected by ``parents[..., component] < cut``."""
        below = parents[..., self.component : self.component + 1] < self.cut
        return torch.where(below, self.low(parents), self.high(parents))


@dataclass(frozen=True)
class Revision:
    """One tested revision and its evidence (held-out log-likelihoods in nats)."""

    kind: str
    variable: str
    detail: str
    loglik_before: float
    loglik_after: float
    gain: float
    accepted: bool
    n_train: int
    n_val: int

    def to_dict(self) -> dict[str, Any]:
        """JSON-compatible fields."""
        return asdict(self)


def _local_graph(graph: CausalGraph, child: str, parents: Sequence[str]) -> CausalGraph:
    """The star pa_i -> X_i (lag_of links to variables outside it are dropped)."""
    names = {*parents, child}
    variables = [
        graph[n] if graph[n].lag_of in (None, *names) else dataclasses.replace(graph[n], lag_of=None)
        for n in graph.names
        if n in names
    ]
    return CausalGraph(variables, [(p, child) for p in parents])


def _trained(
    graph: CausalGraph,
    child: str,
    parents: Sequence[str],
    mech: Mechanism | None,
    train: Mapping[str, Tensor],
    hidden: tuple[int, ...],
    fit_kwargs: Mapping[str, Any],
    discrete: Mapping[str, int],
) -> WorldModel:
    local = _local_graph(graph, child, parents)
    # new weights come from the fit seed, not the global RNG; categorical parents stay categorical
    model = WorldModel(
        local,
        None if mech is None else {child: mech},
        seed=int(fit_kwargs.get("seed", 0)),
        hidden=hidden,
        discrete={k: v for k, v in discrete.items() if k in local},
    )
    if mech is None or not isinstance(mech, SplitMechanism):
        fit(model, {k: v for k, v in train.items() if k in local}, variables=[child], **fit_kwargs)
    return model


def _loglik(model: WorldModel, child: str, val: Mapping[str, Tensor]) -> float:
    with torch.no_grad():
        loc = model.loc(child, val)
        dist = torch.distributions.Normal(loc, model.sigma(child))
        return float(dist.log_prob(val[child]).sum())


def _split(
    graph: CausalGraph,
    child: str,
    parents: Sequence[str],
    train: Mapping[str, Tensor],
    hidden: tuple[int, ...],
    fit_kwargs: Mapping[str, Any],
    discrete: Mapping[str, int],
) -> tuple[WorldModel, str] | None:
    categorical = [p for p in parents if discrete.get(p, 0) > 2]
    if categorical:
        # the split cuts one column of concat(pa_i), which a one-hot parent does not have
        log.info("revise %s: no split candidate: the parents %s are categorical", child, categorical)
        return None
    z = torch.cat([train[p] for p in parents], -1)
    base = _trained(graph, child, parents, None, train, hidden, fit_kwargs, discrete)
    with torch.no_grad():
        resid = (train[child] - base.loc(child, train)).pow(2).sum(-1)
    best = None
    for k in range(z.shape[1]):
        cut = float(z[:, k].median())
        below = z[:, k] < cut
        if int(below.sum()) < 8 or int((~below).sum()) < 8:
            continue
        spread = float(abs(resid[below].mean() - resid[~below].mean()))
        if best is None or spread > best[0]:
            best = (spread, k, cut)
    if best is None:
        return None
    _, k, cut = best
    parts = []
    for mask in (z[:, k] < cut, z[:, k] >= cut):
        sub = {n: v[mask] for n, v in train.items()}
        parts.append(
            _trained(graph, child, parents, None, sub, hidden, fit_kwargs, discrete).mechanism(child)
        )
    mech = SplitMechanism(parts[0], parts[1], k, cut)
    local = _local_graph(graph, child, parents)
    model = WorldModel(
        local,
        {child: mech},
        seed=int(fit_kwargs.get("seed", 0)),
        discrete={k: v for k, v in discrete.items() if k in local},
    )
    with torch.no_grad():
        r = train[child] - model.loc(child, train)
        mech.set_sigma(r.pow(2).mean(0).sqrt().clamp_min(1e-6))
    return model, f"component {k} of concat({', '.join(parents)}) at {cut:.4g}"


def revise(
    model: WorldModel,
    data: Mapping[str, Any],
    variables: Sequence[str],
    *,
    kinds: Sequence[str] = ("add_parent", "capacity", "split"),
    tiers: Sequence[Sequence[str]] | None = None,
    val_fraction: float = 0.3,
    min_gain: float = 10.0,
    hidden: tuple[int, ...] = (32, 32),
    seed: int = 0,
    fit_kwargs: Mapping[str, Any] | None = None,
) -> tuple[WorldModel, list[Revision]]:
    """Propose, test and apply structural revisions for ``variables`` (e.g. ``monitor.flagged()``).

    Args:
        model: the current model (left unchanged).
        data: name -> ``(N, dim)`` recent rows of every variable.
        variables: the variables to revise.
        kinds: revisions to try, from ``("add_parent", "capacity", "split")``.
        tiers: background knowledge for admissible parents (:func:`admissible_parents`).
        val_fraction: held-out share of the rows.
        min_gain: held-out log-likelihood gain (nats) a revision needs to be kept.
        hidden: hidden widths of new MLP mechanisms.
        seed: seeds the split, the new weights and the fits (local generators).
        fit_kwargs: passed to :func:`inference.fit` (default schedule: 60 epochs, batch 256).

    Returns:
        ``(revised model, log)``; the best accepted revision per variable is applied, and the
        revised mechanism is refitted on all rows.

    Raises:
        ValueError: bad data (see :func:`models.world.as_values`), missing columns, unknown
            or root ``variables``, unknown kinds, or a bad setting.
    """
    model = require_world_model(model)
    variables = check_names("variables", variables)
    kinds = check_names("kinds", kinds, allow_empty=False)
    unknown = [k for k in kinds if k not in KINDS]
    if unknown:
        raise ValueError(f"unknown revision kinds {unknown}; expected add_parent, capacity, split")
    val_fraction = check_float(
        "val_fraction", val_fraction, minimum=0.0, maximum=1.0, min_open=True, max_open=True
    )
    min_gain = check_float("min_gain", min_gain)
    hidden = check_hidden(hidden)
    seed = check_seed("seed", seed)
    fit_kwargs = check_keywords("fit_kwargs", fit_kwargs, [k for k in FIT_KWARGS if k != "variables"])
    _check_revisable(model, variables)
    vals, n = _rows(model, data)
    fkw = {"schedule": FitSchedule(epochs=60, batch_size=256), "seed": seed, **fit_kwargs}
    perm = torch.randperm(n, generator=torch.Generator().manual_seed(seed))
    n_val = max(1, round(val_fraction * n))
    val = {k: v[perm[:n_val]] for k, v in vals.items()}
    train = {k: v[perm[n_val:]] for k, v in vals.items()}
    allowed = admissible_parents(model.graph, tiers=tiers)
    current = model
    log_: list[Revision] = []
    for child in variables:
        parents = list(current.graph.parents(child))
        fitting = _Fitting(train, hidden, fkw, model.discrete, seed)
        baseline = fitting.trained(current.graph, child, parents, copy.deepcopy(current.mechanism(child)))
        before = _loglik(baseline, child, val)
        candidates = _candidates(current, model.graph, child, parents, kinds, allowed[child], fitting)
        best = _best(candidates, child, before, val, min_gain, (n - n_val, n_val), log_)
        if best is None:
            log.info("revise %s: no revision beats the current mechanism by %.1f nats", child, min_gain)
            continue
        rev, cand, new_parents = best
        log_[log_.index(rev)] = Revision(**{**rev.to_dict(), "accepted": True})
        current = _applied(model, current, child, parents, cand, new_parents, vals, fitting)
        current.provenance = {
            **model.provenance,
            "revisions": [*model.provenance.get("revisions", []), rev.to_dict() | {"accepted": True}],
        }
        log.info("revise %s: kept %s (%s), +%.1f nats held out", child, rev.kind, rev.detail, rev.gain)
    if not math.isfinite(sum(r.gain for r in log_)):
        raise FloatingPointError("a revision produced a non-finite log-likelihood")
    return current, log_


def _best(
    candidates: Sequence[tuple[str, str, WorldModel, list[str]]],
    child: str,
    before: float,
    val: Mapping[str, Tensor],
    min_gain: float,
    rows: tuple[int, int],
    log_: list[Revision],
) -> tuple[Revision, WorldModel, list[str]] | None:
    """The candidate with the best held-out gain above ``min_gain``, each scored one logged in ``log_``.

    ``rows`` are the numbers of training and held-out rows.
    """
    best = None
    for kind, detail, cand, new_parents in candidates:
        after = _loglik(cand, child, val)
        gain = after - before
        rev = Revision(kind, child, detail, before, after, gain, False, *rows)
        log_.append(rev)
        if gain > min_gain and (best is None or gain > best[0].gain):
            best = (rev, cand, new_parents)
    return best


def _check_revisable(model: WorldModel, variables: Sequence[str]) -> None:
    """Refuse unknown, root and discrete variables."""
    for child in variables:
        model.graph.check_name(child, what="variable to revise")
        if model.graph.is_root(child):
            raise ValueError(f"{child!r} is a root; only mechanisms can be revised")
        if child in model.discrete:
            raise ValueError(
                f"{child!r} is a discrete site; revise scores Gaussian mechanisms by their held-out "
                "likelihood and does not revise discrete ones"
            )


def _rows(model: WorldModel, data: Mapping[str, Any]) -> tuple[dict[str, Tensor], int]:
    """Name -> ``(N, dim)`` rows of every variable, at least 4 of them."""
    vals, n = as_values(model.graph, data, what="data", dtype=model.dtype)
    missing = [v for v in model.graph.names if v not in vals]
    if missing:
        raise ValueError(f"revise needs rows of every variable; missing {missing}")
    if n < 4:
        raise ValueError(
            f"revise needs at least 4 rows of data to split into training and validation, got {n}"
        )
    return vals, n


@dataclass(frozen=True)
class _Fitting:
    """How :func:`revise` trains a candidate: training rows, hidden widths, fit keywords, seed."""

    train: Mapping[str, Tensor]
    hidden: tuple[int, ...]
    fit_kwargs: Mapping[str, Any]
    discrete: Mapping[str, int]
    seed: int

    def trained(
        self, graph: CausalGraph, child: str, parents: Sequence[str], mech: Mechanism | None
    ) -> WorldModel:
        """The star ``parents -> child`` with ``mech`` (or a new MLP) trained on the rows."""
        return _trained(graph, child, parents, mech, self.train, self.hidden, self.fit_kwargs, self.discrete)


def _candidates(
    current: WorldModel,
    graph: CausalGraph,
    child: str,
    parents: list[str],
    kinds: Sequence[str],
    allowed: Sequence[str],
    fitting: _Fitting,
) -> list[tuple[str, str, WorldModel, list[str]]]:
    """The trained candidates ``(kind, detail, model, parents)`` for one variable."""
    candidates: list[tuple[str, str, WorldModel, list[str]]] = []
    if "add_parent" in kinds:
        desc = current.graph.descendants(child)
        for j in allowed:
            if j in parents or j in desc:
                continue
            new_parents = [p for p in graph.names if p in {*parents, j}]
            cand = fitting.trained(current.graph, child, new_parents, None)
            candidates.append(("add_parent", f"{j} -> {child}", cand, new_parents))
    if "capacity" in kinds:
        hidden = fitting.hidden
        mech = current.mechanism(child)
        width = max(getattr(mech, "hidden", hidden) or hidden)
        bigger = tuple([2 * width] * (len(getattr(mech, "hidden", hidden)) + 1))
        cand_mech = MLPMechanism(mech.in_dim, mech.out_dim, hidden=bigger, seed=fitting.seed)
        cand = fitting.trained(current.graph, child, parents, cand_mech)
        candidates.append(("capacity", f"MLP hidden {list(bigger)}", cand, parents))
    if "split" in kinds and parents:
        split = _split(
            current.graph, child, parents, fitting.train, fitting.hidden, fitting.fit_kwargs, fitting.discrete
        )
        if split is not None:
            candidates.append(("split", split[1], split[0], parents))
    return candidates


def _applied(
    model: WorldModel,
    current: WorldModel,
    child: str,
    parents: Sequence[str],
    cand: WorldModel,
    new_parents: Sequence[str],
    vals: Mapping[str, Tensor],
    fitting: _Fitting,
) -> WorldModel:
    """``current`` with the accepted candidate's edges and mechanism, refitted on all rows."""
    seed, hidden, discrete = fitting.seed, fitting.hidden, fitting.discrete
    edited = current.graph.with_edges(add=[(p, child) for p in new_parents if p not in parents])
    mech = cand.mechanism(child)
    fresh = current.with_graph(edited, seed=seed)
    mechs = {v: fresh.mechanism(v) for v in edited.non_roots}
    mechs[child] = mech
    out = WorldModel(edited, mechs, seed=seed, hidden=hidden, discrete=discrete)
    out.copy_root_priors_from(model)
    if not isinstance(mech, SplitMechanism):
        fit(out, {k: v for k, v in vals.items()}, variables=[child], **fitting.fit_kwargs)
    return out
