"""World-model contextualisation (thesis §6.4.2, Eq. 6.4-6.7).

For the additive-noise mechanisms X_i = f_i(x_pa(i)) + U_i:

    local sensitivity (6.5):      r_{j->i}(x^C) = || d f_i / d x_j ||   at the context's parent values
    context-averaged (6.6):       R_{j->i}      = E_{x ~ p(x | C)} || d f_i / d x_j ||
    target relevance (6.7):       r_{j->tar}(x^C) = || d Phi^tar / d x_j ||

with Frobenius norms of Jacobian blocks for vector variables. Phi^tar is the forward query
(Eq. 4.44) from the context's root values to the targets; d/dx_j is the derivative of the
targets when x_j is shifted (as by ``do``), all other exogenous terms fixed. Both are
reported raw (units of child per unit of parent) and standardised (times sd(x_j) / sd(x_i)
over the context samples), which makes a threshold unit-free.

The active subgraph G^C (Eq. 6.4) keeps the targets, every variable with a directed path to
a target through edges whose standardised R is at least ``threshold``, and those edges. A
mechanism whose pruned parents it still reads gets them clamped at their context mean.
:func:`subgraph_model` builds that smaller :class:`WorldModel`; action inference on it is
the whole-graph answer when the pruned parts do not reach the targets, and cheaper.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor

from models.checks import check_bool, check_float, check_names, describe
from models.graph import CausalGraph
from models.mechanisms import FunctionMechanism, Mechanism
from models.world import WorldModel, as_values, require_world_model

__all__ = [
    "ActiveSubgraph",
    "active_subgraph",
    "context_sensitivity",
    "local_sensitivity",
    "refuse_categorical_parents",
    "subgraph_model",
    "target_relevance",
]

Edge = tuple[str, str]


def refuse_categorical_parents(model: WorldModel, what: str, names: Sequence[str] | None = None) -> None:
    """Refuse categorical parents with K > 2: f_i reads them one-hot, so d f_i / d x_j does not exist.

    A Bernoulli parent (K = 2) enters f_i as its 0/1 code, and its derivative is that of
    the code taken as a real number.

    Raises:
        ValueError: naming the categorical parents (among ``names``, default all) and K.
    """
    g = model.graph
    bad = {
        p: k for p, k in model.discrete.items() if k > 2 and g.children(p) and (names is None or p in names)
    }
    if bad:
        raise ValueError(
            f"{what} differentiates the mechanisms with respect to their parents, but the categorical "
            f"parents {bad} (name: K) enter them one-hot and have no derivative; contextualise a model "
            "without categorical parents of more than 2 categories (or condition on them: fix them with do)"
        )


def _values(model: WorldModel, values: Mapping[str, Any]) -> dict[str, Tensor]:
    require_world_model(model)
    refuse_categorical_parents(model, "contextualisation")
    vals, _ = as_values(model.graph, values, what="context", dtype=model.dtype)
    missing = [v for v in model.graph.names if v not in vals]
    if missing:
        raise ValueError(
            f"context needs a value for every variable; missing {missing} (use model.predict to complete it)"
        )
    return {k: v.detach() for k, v in vals.items()}


def local_sensitivity(model: WorldModel, values: Mapping[str, Any]) -> dict[Edge, Tensor]:
    """Eq. 6.5 per unit: edge (j, i) -> ``(N,)`` ||d f_i / d x_j|| at the given values.

    Args:
        model: the world model.
        values: name -> ``(N, dim)`` for every variable (the contexts x^C).
    """
    vals = _values(model, values)
    g = model.graph
    out: dict[Edge, Tensor] = {}
    for child in g.non_roots:
        parents = g.parents(child)
        inputs = {p: vals[p].clone().requires_grad_(True) for p in parents}
        with torch.enable_grad():
            loc = model.loc(child, inputs)  # (N, d_i)
            sq = {p: torch.zeros(loc.shape[0], dtype=loc.dtype) for p in parents}
            for k in range(loc.shape[1]):
                grads = torch.autograd.grad(loc[:, k].sum(), [inputs[p] for p in parents], retain_graph=True)
                for p, gr in zip(parents, grads, strict=True):
                    sq[p] = sq[p] + gr.pow(2).sum(-1)
        for p in parents:
            out[p, child] = sq[p].sqrt()
    return out


def _scales(values: Mapping[str, Tensor]) -> dict[str, float]:
    return {k: float(v.std(0, unbiased=False).norm()) if v.shape[0] > 1 else 1.0 for k, v in values.items()}


def context_sensitivity(
    model: WorldModel, samples: Mapping[str, Any], standardise: bool = True
) -> dict[Edge, float]:
    """Eq. 6.6: edge -> mean over the context samples of ||d f_i / d x_j||.

    Args:
        model: the world model.
        samples: name -> ``(N, dim)`` draws from p(x | C) (e.g. recent data or
            ``model.sample``) for every variable.
        standardise: multiply by sd(x_j) / sd(x_i) over the samples (unit-free).
    """
    standardise = check_bool("standardise", standardise)
    vals = _values(model, samples)
    local = local_sensitivity(model, vals)
    sd = _scales(vals)
    out = {}
    for (p, c), r in local.items():
        scale = sd[p] / sd[c] if standardise and sd[c] > 0 else 1.0
        out[p, c] = float(r.mean()) * scale
    return out


def target_relevance(
    model: WorldModel, values: Mapping[str, Any], targets: Sequence[str], standardise: bool = False
) -> dict[str, Tensor]:
    """Eq. 6.7 per unit: variable j -> ``(N,)`` ||d Phi^tar / d x_j|| (0 for non-ancestors of the targets).

    Args:
        model: the world model.
        values: name -> ``(N, dim)``; the roots are the assignment Phi starts from, the
            other values only give the scales when ``standardise``.
        targets: target variable names.
        standardise: multiply by sd(x_j) / sd(targets) over the N units.
    """
    g = require_world_model(model).graph
    refuse_categorical_parents(model, "target relevance")
    standardise = check_bool("standardise", standardise)
    targets = check_names("targets", targets, allow_empty=False)
    for t in targets:
        g.check_name(t, what="target")
    vals, n = as_values(g, values, what="context", dtype=model.dtype)
    missing = [r for r in g.roots if r not in vals]
    if missing:
        raise ValueError(f"target relevance needs values of every root; missing {missing}")
    leaves = {r: vals[r].detach().clone().requires_grad_(True) for r in g.roots}
    shift = {v: torch.zeros(n, g[v].dim, dtype=model.dtype, requires_grad=True) for v in g.non_roots}
    with torch.enable_grad():
        x: dict[str, Tensor] = dict(leaves)
        for v in g.non_roots:
            x[v] = model.loc(v, x) + shift[v]
        out_t = torch.cat([x[t] for t in targets], -1)  # (N, D_tar)
        wrt = {**leaves, **shift}
        names = list(wrt)
        sq = {k: torch.zeros(n, dtype=model.dtype) for k in names}
        for k in range(out_t.shape[1]):
            grads = torch.autograd.grad(
                out_t[:, k].sum(), [wrt[m] for m in names], retain_graph=True, allow_unused=True
            )
            for m, gr in zip(names, grads, strict=True):
                if gr is not None:
                    sq[m] = sq[m] + gr.pow(2).sum(-1)
    rel = {m: sq[m].sqrt() for m in names}
    if standardise:
        full = {k: v.detach() for k, v in x.items()}
        sd = _scales(full)
        sd_t = float(torch.cat([full[t] for t in targets], -1).std(0, unbiased=False).norm()) or 1.0
        rel = {m: r * sd[m] / sd_t for m, r in rel.items()}
    return rel


@dataclass(frozen=True)
class ActiveSubgraph:
    """The active subgraph G^C of a query (Eq. 6.4).

    Attributes:
        graph: the subgraph (variables keep their roles; pruned parents make some roots).
        sensitivity: standardised R_{j->i} of every edge of the full graph.
        clamped: child -> {pruned parent: its context mean ``(dim,)``}.
        dropped: variables outside G^C.
    """

    graph: CausalGraph
    sensitivity: dict[Edge, float]
    clamped: dict[str, dict[str, Tensor]]
    dropped: tuple[str, ...]


def active_subgraph(
    model: WorldModel, samples: Mapping[str, Any], targets: Sequence[str], threshold: float = 0.01
) -> ActiveSubgraph:
    """Extract G^C: the targets and everything with a relevant directed path to them.

    The lag-0 partner (``lag_of``) of every kept lag-1 variable is kept too, with its own
    relevant ancestors: it carries the state to the next step of a rollout.

    Args:
        model: the world model.
        samples: name -> ``(N, dim)`` context samples of every variable.
        targets: the query's target variables.
        threshold: smallest standardised R_{j->i} for an edge to stay active, >= 0.
    """
    threshold = check_float("threshold", threshold, minimum=0.0)
    g = require_world_model(model).graph
    targets = check_names("targets", targets)
    if not targets:
        raise ValueError("targets is empty; name at least one target variable")
    for t in targets:
        g.check_name(t, what="target")
    vals = _values(model, samples)
    sens = context_sensitivity(model, vals)
    active = {e for e, r in sens.items() if r >= threshold}
    keep: set[str] = set()
    frontier: list[str] = []

    def add(name: str) -> None:
        # a kept lag-1 root carries its lag-0 partner's value to the next step: keep the partner
        while name is not None and name not in keep:
            keep.add(name)
            frontier.append(name)
            name = g[name].lag_of

    for t in targets:
        add(t)
    while frontier:
        child = frontier.pop()
        for p in g.parents(child):
            if (p, child) in active:
                add(p)
    names = [n for n in g.names if n in keep]
    edges = [(p, c) for p, c in g.edges if p in keep and c in keep and (p, c) in active]
    clamped: dict[str, dict[str, Tensor]] = {}
    for c in names:
        pruned = [p for p in g.parents(c) if (p, c) not in edges]
        if pruned and any((p, c) in edges for p in g.parents(c)):
            clamped[c] = {p: vals[p].mean(0) for p in pruned}
    sub = CausalGraph([g[n] for n in names], edges)
    return ActiveSubgraph(sub, sens, clamped, tuple(n for n in g.names if n not in keep))


def _clamped_mechanism(
    model: WorldModel, child: str, kept: Sequence[str], fixed: Mapping[str, Tensor]
) -> Mechanism:
    """f_i reading only ``kept`` parents, with the others fixed at ``fixed`` values."""
    g = model.graph
    full = model.mechanism(child)
    parents = g.parents(child)
    dims = {p: model.parent_width(p) for p in parents}  # a categorical parent is read one-hot

    def fn(z: Tensor) -> Tensor:
        parts, start = {}, 0
        for p in kept:
            parts[p] = z[..., start : start + dims[p]]
            start += dims[p]
        batch = z.shape[:-1]
        cols = [parts[p] if p in parts else fixed[p].expand(*batch, dims[p]) for p in parents]
        return full(torch.cat(cols, -1))

    mech = FunctionMechanism(fn, sum(dims[p] for p in kept), g[child].dim)
    mech.set_sigma(full.sigma.detach())
    return mech


def subgraph_model(model: WorldModel, sub: ActiveSubgraph) -> WorldModel:
    """A :class:`WorldModel` on ``sub.graph`` that shares the kept mechanisms of ``model``.

    Mechanisms with all parents kept are the same modules (no copy); the others read their
    pruned parents at the clamped context values. Variables that became roots get the
    Normal prior N(0, 1) (give them as state in queries).
    """
    model = require_world_model(model)
    if not isinstance(sub, ActiveSubgraph):
        raise ValueError(f"sub must be an ActiveSubgraph from active_subgraph, got {describe(sub)}")
    g = sub.graph
    foreign = [v for v in g.names if v not in model.graph or model.graph[v] != g[v]]
    if foreign:
        raise ValueError(f"sub names variables {foreign} that are not variables of the model")
    clamped_parents = sorted({p for fixed in sub.clamped.values() for p in fixed})
    refuse_categorical_parents(model, "clamping pruned parents at their context mean", clamped_parents)
    mechs: dict[str, Mechanism] = {}
    for c in g.non_roots:
        if c in sub.clamped:
            mechs[c] = _clamped_mechanism(model, c, g.parents(c), sub.clamped[c])
        else:
            mechs[c] = model.mechanism(c)
    out = WorldModel(g, mechs, discrete={k: v for k, v in model.discrete.items() if k in g})
    out.copy_root_priors_from(model)
    out.provenance = {
        **model.provenance,
        "subgraph_of": model.graph.fingerprint(),
        "dropped": list(sub.dropped),
    }
    return out
