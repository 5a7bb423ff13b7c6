"""Active experimental design for structure learning (thesis §4.3.2, regime 3).

Which variable should the agent set by ``do`` next, so that the learnt graph improves most?
Observational data leave two kinds of doubt about an edge p -> c of the learnt graph:

- existence: its confidence c_pc = sigmoid(Delta_pc) (:mod:`inference.discovery`);
- orientation: the held-out margin of p -> c over c -> p,

      M_pc = [S_c(pa_c) + S_p(pa_p)] - [S_c(pa_c - p) + S_p(pa_p + c)]   (nats),

  infinite when reversing would close a cycle through another path.

An intervention on X_j cuts f_j and so tests exactly the edges incident to j. The
uncertainty of a variable is

    U_j = sum_{edges e incident to j} [ sigmoid(-M_e) + (1 - c_e) ],

and :func:`choose_interventions` spreads a budget of interventions greedily with
diminishing returns: each next one goes to argmax_j (U_j + mean U) / (1 + n_j)^2, where
n_j counts the interventions already given to X_j. Actions are skipped (they are set by
``do`` anyway).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import networkx as nx

from inference.admissible import StructureData, as_variables
from inference.crossfit import RepeatedScorer
from inference.discovery import DiscoveryResult, sigmoid
from inference.marginals import transform_columns
from models.checks import check_float, check_int, check_mapping, describe
from models.variables import Role

__all__ = ["choose_interventions", "orientation_margins", "structure_uncertainty"]


def orientation_margins(
    result: DiscoveryResult,
    data: Mapping[str, Any],
    *,
    intervened: Mapping[str, Any] | None = None,
) -> dict[tuple[str, str], float]:
    """M_pc in nats for every learnt edge (``math.inf`` when it cannot be reversed).

    Args:
        result: a :func:`inference.discovery.discover` result.
        data: name -> ``(N, dim)`` values it was learnt from (as for ``discover``).
        intervened: name -> ``(N,)`` bool ``do`` masks it was learnt with (as for ``discover``).
    """
    graph = _check_result(result).graph
    vs = as_variables(graph)
    settings = result.settings
    if isinstance(data, Mapping):  # the columns discover transformed, transformed alike
        data = transform_columns(data, settings.get("transform", "none"))[0]
    sdata = StructureData.build(vs, data, intervened)
    scorer = RepeatedScorer(
        sdata,
        repeats=settings.get("repeats", 1),
        features=settings["features"],
        ridge=settings["ridge"],
        folds=settings["folds"],
        length=settings["length"],
        floor=settings["floor"],
        seed=settings["seed"],
    )
    g = graph.nx
    index = {n: i for i, n in enumerate(graph.names)}

    def local(child: str, parents: set[str]) -> float:
        return float(scorer.score(child, [tuple(sorted(parents, key=index.__getitem__))])[0])

    out: dict[tuple[str, str], float] = {}
    for p, c in graph.edges:
        pv, cv = graph[p], graph[c]
        g.remove_edge(p, c)
        blocked = nx.has_path(g, p, c) or pv.role is Role.ACTION or (cv.lag == 0 and pv.lag == 1)
        g.add_edge(p, c)
        if blocked:
            out[p, c] = math.inf
            continue
        pa_c, pa_p = set(graph.parents(c)), set(graph.parents(p))
        now = local(c, pa_c) + local(p, pa_p)
        flipped = local(c, pa_c - {p}) + local(p, pa_p | {c})
        out[p, c] = now - flipped
    return out


def _check_result(result: object) -> DiscoveryResult:
    if not isinstance(result, DiscoveryResult):
        raise ValueError(f"result must be a DiscoveryResult from inference.discover, got {describe(result)}")
    return result


def structure_uncertainty(
    result: DiscoveryResult, margins: Mapping[tuple[str, str], float]
) -> dict[str, float]:
    """U_j for every variable (0 for variables without incident edges)."""
    result = _check_result(result)
    margins = check_mapping("margins", margins)
    out = dict.fromkeys(result.graph.names, 0.0)
    edges = set(result.graph.edges)
    for key, m in margins.items():
        if key not in edges:
            raise ValueError(f"margins names {key!r}, which is not an edge of the learnt graph")
        check_float(f"margin of {key!r}", m, finite=False)
    for (p, c), m in margins.items():
        conf = result.graph.confidence.get((p, c), 1.0)
        u = (1.0 - sigmoid(m)) + (1.0 - conf)
        out[p] += u
        out[c] += u
    return out


def choose_interventions(
    result: DiscoveryResult, margins: Mapping[tuple[str, str], float], budget: int
) -> list[str]:
    """Spread ``budget`` interventions over the non-action variables (see the module docstring).

    Returns:
        ``budget`` target names (repeated), most uncertain variables first. With no
        uncertainty at all the budget goes round-robin over the non-action variables.
    """
    budget = check_int("budget", budget, minimum=0)
    graph = _check_result(result).graph
    u = {k: v for k, v in structure_uncertainty(result, margins).items() if graph[k].role is not Role.ACTION}
    total = sum(u.values())
    if budget == 0:
        return []
    if total <= 0:
        names = sorted(u)
        return [names[k % len(names)] for k in range(budget)]
    # greedy allocation with diminishing returns: the next intervention goes to
    # argmax (U_j + u0) / (1 + n_j)^2, u0 = mean U (so every variable is tested eventually)
    u0 = total / len(u)
    counts = dict.fromkeys(u, 0)
    for _ in range(budget):
        best = max(sorted(u), key=lambda k: (u[k] + u0) / (1 + counts[k]) ** 2)
        counts[best] += 1
    ranked = sorted(counts, key=lambda k: -u[k])
    return [k for k in ranked for _ in range(counts[k])]
