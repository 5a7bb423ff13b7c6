"""Structure learning for the world model: parent sets from observational and interventional data.

The learnt graph maximises the held-out likelihood of the additive-noise SCM

    X_i = f_i(pa_i) + U_i,    log L(G) = sum_i S_i(pa_i)

(:mod:`inference.crossfit`), over DAGs whose edges are admissible (:mod:`inference.admissible`):
actions are roots, no edge runs backwards in time, and any tiers or forbidden/required
edges hold. Rows where X_i was set by ``do`` are left out of S_i, so interventions orient
edges that observational data cannot.

Pipeline:

1. Search (:mod:`inference.search`): from the required edges, greedily add the admissible,
   acyclic edge with the largest held-out gain S_i(pa_i + j) - S_i(pa_i) while it exceeds
   ``min_gain`` nats (CAM-style), then hill-climb with additions, removals and reversals
   (best first) to repair edges oriented wrongly early on. Its topological order fixes the
   direction of every later edge.
2. Sparsify (optional, ``sparsify="gated"``): start again from *all* admissible parents
   that precede the child in that order, train group-lasso-gated MLPs
   (:mod:`inference.gated`) over a penalty path, and keep per child the parent set of the
   penalty with the best held-out likelihood.
3. Prune: backward elimination of every edge whose held-out log-likelihood ratio
   Delta_ji = S_i(pa_i) - S_i(pa_i - j) falls below ``prune_nats``.

Each kept edge carries the confidence sigmoid(Delta_ji): its posterior probability against
its removal under even prior odds, judged on held-out rows.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from inference.admissible import StructureData, admissible_parents, as_variables
from inference.crossfit import RepeatedScorer
from inference.search import Dag, LocalScores, hill_climb
from models.checks import check_choice, check_edges, check_float, check_int, check_keywords, check_seed
from models.graph import CausalGraph

__all__ = ["DiscoveryResult", "discover", "shd", "sigmoid"]

#: Keyword arguments of :func:`inference.gated.select_parents` that ``gated`` may set.
GATED_KWARGS = ("penalties", "hidden", "steps", "lr", "val_fraction")

log = logging.getLogger(__name__)

SPARSIFIERS = ("none", "gated")


@dataclass(frozen=True)
class DiscoveryResult:
    """A learnt graph and its evidence.

    Attributes:
        graph: the learnt :class:`CausalGraph`; every edge carries a confidence in (0.5, 1].
        log_ratio: edge -> held-out log-likelihood ratio Delta_ji (nats) against removing it.
        order: the topological order found by the search.
        history: the search moves, ``(move, parent, child, gain in nats)`` in the order
            taken; move is ``"add"``, ``"remove"`` or ``"reverse"``.
        score: held-out log-likelihood of the final graph, nats (sum over variables).
        evaluations: candidate parent sets scored.
        seconds: wall time.
    """

    graph: CausalGraph
    log_ratio: dict[tuple[str, str], float]
    order: tuple[str, ...]
    history: tuple[tuple[str, str, str, float], ...]
    score: float
    evaluations: int
    seconds: float
    settings: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """JSON-compatible summary (graph JSON included)."""
        return {
            "graph": self.graph.to_dict(),
            "edges": [
                {
                    "parent": p,
                    "child": c,
                    "confidence": self.graph.confidence[p, c],
                    "log_ratio": self.log_ratio[p, c],
                }
                for p, c in self.graph.edges
            ],
            "order": list(self.order),
            "history": [list(h) for h in self.history],
            "score": self.score,
            "evaluations": self.evaluations,
            "seconds": self.seconds,
            "settings": dict(self.settings),
        }


def shd(
    learnt: CausalGraph | Iterable[tuple[str, str]], truth: CausalGraph | Iterable[tuple[str, str]]
) -> int:
    """Structural Hamming distance: missing + extra edges, a reversed edge counting once.

    Args:
        learnt: a graph or a sequence of ``(parent, child)`` name pairs.
        truth: the reference graph, in the same forms.
    """
    a = set(learnt.edges if isinstance(learnt, CausalGraph) else check_edges("learnt", learnt))
    b = set(truth.edges if isinstance(truth, CausalGraph) else check_edges("truth", truth))
    reversed_ = {(p, c) for p, c in a - b if (c, p) in b}
    return len(a - b) + len(b - a) - len(reversed_)


def _prune(
    scores: LocalScores,
    dag_parents: dict[str, list[str]],
    index: Mapping[str, int],
    prune_nats: float,
    required: set[tuple[str, str]],
) -> tuple[dict[tuple[str, str], float], float]:
    """Backward elimination per child; returns edge -> Delta and the total score."""
    ratios: dict[tuple[str, str], float] = {}
    total = 0.0
    for child, parents in dag_parents.items():
        while True:
            full = scores.one(child, tuple(parents))
            if not parents:
                total += full
                break
            reduced = scores.many(child, [tuple(q for q in parents if q != p) for p in parents])
            deltas = {p: full - r for p, r in zip(parents, reduced, strict=True)}
            free = {p: d for p, d in deltas.items() if (p, child) not in required}
            weakest = min(free, key=free.__getitem__) if free else None
            if weakest is not None and free[weakest] < prune_nats:
                parents = sorted((q for q in parents if q != weakest), key=index.__getitem__)
                continue
            total += full
            ratios.update({(p, child): d for p, d in deltas.items()})
            break
        dag_parents[child] = parents
    return ratios, total


def sigmoid(x: float) -> float:
    """Logistic function ``1 / (1 + exp(-x))`` without overflow; 1 at inf and 0 at -inf."""
    if x >= 0:
        return 1.0 / (1.0 + math.exp(-x))
    e = math.exp(x)
    return e / (1.0 + e)


def discover(
    variables: CausalGraph | Sequence[Any],
    data: Mapping[str, Any],
    *,
    intervened: Mapping[str, Any] | None = None,
    tiers: Sequence[Sequence[str]] | None = None,
    forbidden: Iterable[tuple[str, str]] = (),
    required: Iterable[tuple[str, str]] = (),
    min_gain: float = 10.0,
    prune_nats: float = 5.0,
    min_reverse: float = 1.0,
    max_parents: int | None = None,
    max_moves: int = 10_000,
    sparsify: str = "none",
    features: int = 64,
    ridge: float | Sequence[float] = (1e-3, 1e-2, 1e-1, 1.0),
    folds: int = 2,
    length: float | Sequence[float] = (0.7, 2.0),
    floor: float = 1e-6,
    repeats: int = 1,
    gated: Mapping[str, Any] | None = None,
    seed: int = 0,
) -> DiscoveryResult:
    """Learn the parent sets of the world model from data.

    Args:
        variables: a :class:`CausalGraph` (its edges are ignored) or a list of ``Variable``.
        data: name -> ``(N, dim)`` values of every variable; each column is standardised
            on its non-intervened rows before anything else.
        intervened: name -> ``(N,)`` bool, True where the variable was set by ``do``;
            those rows do not enter that variable's mechanism likelihood. Actions need no
            mask: they are roots.
        tiers: optional ordered groups of names; a parent must be in the same or an earlier
            tier (:func:`admissible_parents`).
        forbidden: ``(parent, child)`` edges that may not appear.
        required: ``(parent, child)`` edges that must appear.
        min_gain: smallest held-out gain (nats) for the search to add an edge.
        prune_nats: edges with a smaller held-out log-likelihood ratio are removed.
        min_reverse: smallest held-out gain (nats) for the search to reverse an edge.
        max_parents: optional cap on |pa_i| during the search.
        max_moves: cap on the moves of each search phase.
        sparsify: ``"none"`` or ``"gated"`` (group-lasso MLP selection from all admissible
            parents consistent with the search order).
        features: random Fourier features M of the held-out scorer (:class:`CrossFitScorer`).
        ridge: ridge penalties on the feature weights to choose from.
        folds: cross-fitting folds K >= 2.
        length: RBF length scale(s) per sqrt(|P|) to choose from, in standard deviations.
        floor: smallest residual variance, in standardised units.
        repeats: average the score over this many fold splits and feature draws
            (:class:`RepeatedScorer`); costs ``repeats`` times as much.
        gated: keyword arguments for :func:`inference.gated.select_parents`.
        seed: seeds the folds, the random features and the gated MLPs.

    Returns:
        :class:`DiscoveryResult` whose graph carries an edge confidence.

    Raises:
        ValueError: bad variables, data, masks or background knowledge (unknown names,
            non-float columns, wrong shapes, NaN, fewer than 8 rows), or a setting of the
            wrong type or range.
    """
    start = time.perf_counter()
    sparsify = check_choice("sparsify", sparsify, SPARSIFIERS)
    min_gain = check_float("min_gain", min_gain)
    prune_nats = check_float("prune_nats", prune_nats)
    min_reverse = check_float("min_reverse", min_reverse)
    if not prune_nats <= min_gain:
        raise ValueError(f"prune_nats ({prune_nats}) must be <= min_gain ({min_gain})")
    if max_parents is not None:
        max_parents = check_int("max_parents", max_parents, minimum=1)
    max_moves = check_int("max_moves", max_moves, minimum=1)
    seed = check_seed("seed", seed)
    gated = check_keywords("gated", gated, GATED_KWARGS)
    vs = as_variables(variables)
    required = set(check_edges("required", required))
    allowed = admissible_parents(vs, tiers=tiers, forbidden=forbidden, required=required)
    sdata = StructureData.build(vs, data, intervened)
    scorer = RepeatedScorer(
        sdata,
        repeats=repeats,
        features=features,
        ridge=ridge,
        folds=folds,
        length=length,
        floor=floor,
        seed=seed,
    )
    scores = LocalScores(scorer)
    dag = Dag(sdata.names)
    for p, c in sorted(required, key=lambda e: (dag.index[e[1]], dag.index[e[0]])):
        dag.add(p, c)
    history = hill_climb(
        scores,
        allowed,
        dag,
        min_gain=min_gain,
        prune_nats=prune_nats,
        min_reverse=min_reverse,
        max_parents=max_parents,
        required=required,
        max_moves=max_moves,
    )
    order = dag.order()
    parents = {n: list(ps) for n, ps in dag.parents.items()}
    if sparsify == "gated":
        from inference.gated import select_parents

        position = {n: k for k, n in enumerate(order)}
        candidates = {c: tuple(p for p in allowed[c] if position[p] < position[c]) for c in sdata.names}
        chosen = select_parents(sdata, candidates, seed=seed, **gated)
        parents = {
            c: sorted({*chosen[c], *(p for p, cc in required if cc == c)}, key=dag.index.__getitem__)
            for c in sdata.names
        }
    ratios, total = _prune(scores, parents, dag.index, prune_nats, required)
    edges = [(p, c) for c in sdata.names for p in parents[c]]
    confidence = {e: sigmoid(ratios[e]) for e in edges}
    graph = CausalGraph(vs, edges, confidence)
    seconds = time.perf_counter() - start
    log.info(
        "discover: %d edges over %d variables in %.2f s (%d sets scored)",
        len(edges),
        len(vs),
        seconds,
        scorer.calls,
    )
    settings = {
        "min_gain": min_gain,
        "prune_nats": prune_nats,
        "min_reverse": min_reverse,
        "max_parents": max_parents,
        "sparsify": sparsify,
        "features": features,
        "ridge": ridge,
        "folds": folds,
        "length": length,
        "floor": floor,
        "repeats": repeats,
        "seed": seed,
        "intervened_rows": {k: int((~v).sum()) for k, v in sdata.rows.items() if not bool(v.all())},
    }
    return DiscoveryResult(
        graph,
        {e: float(ratios[e]) for e in edges},
        order,
        tuple(history),
        float(total),
        scorer.calls,
        seconds,
        settings,
    )
