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
its removal under even prior odds, judged on held-out rows. With ``options.bootstrap = B``
the whole pipeline is repeated on B random subsamples of the rows (without replacement, a
share ``options.subsample`` each), and :attr:`DiscoveryResult.stability` is the share of
them whose graph holds each edge (stability selection). The result also carries the CPDAG
of the learnt DAG under the background knowledge (:mod:`inference.equivalence`), which shows
the edges observational data cannot orient; :func:`shd` documents how reversed and
undirected edges count, and :func:`inference.equivalence.compare_edges` compares with a
reference graph that has cycles.

**Which graph to compare with a peer's.** :attr:`DiscoveryResult.graph` is a DAG oriented by
held-out likelihoods (nonlinear additive noise and interventions orient edges that the
equivalence class leaves open); :attr:`DiscoveryResult.cpdag` keeps only what v-structures and
background knowledge imply. Against a reference DAG, compare ``shd(result.graph, truth)`` with
the peer's CPDAG scored against that DAG (:func:`pal.baselines.discovery_peers.cpdag_shd`, an
undirected edge counting 1); to compare equivalence classes, score ``result.cpdag`` and the
peer's CPDAG against ``cpdag(truth)``. pal's CPDAG against a DAG is charged for every
orientation it found and gave up.

Robustness: skewed or heavy-tailed columns enter as normal scores (``options.transform``,
:mod:`inference.marginals`), and an edge needs a held-out gain of ``prune_nats`` and of
``min_z`` standard errors (:mod:`inference.prune`): it must earn its place on many rows.

``discover(table)`` takes a pandas DataFrame, a :class:`models.tables.Table` or a mapping of
1-d columns directly: every column becomes an observed scalar variable named by the table
name rule (:mod:`models.tables`).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from tqdm.auto import tqdm

from inference.admissible import StructureData, admissible_parents, as_variables
from inference.crossfit import CrossFitScorer, RepeatedScorer
from inference.equivalence import CPDAG, compare_edges, cpdag
from inference.marginals import TRANSFORMS, transform_columns
from inference.prune import prune
from inference.search import Dag, LocalScores, hill_climb
from inference.stability import edge_stability
from models.checks import (
    check_bool,
    check_choice,
    check_edges,
    check_float,
    check_int,
    check_keywords,
    check_seed,
)
from models.graph import CausalGraph
from models.tables import as_table, is_table

__all__ = ["DiscoveryOptions", "DiscoveryResult", "discover", "shd", "sigmoid"]

#: Keyword arguments of :func:`inference.gated.select_parents` that ``gated`` may set.
GATED_KWARGS = ("penalties", "hidden", "steps", "lr", "val_fraction")

log = logging.getLogger(__name__)

SPARSIFIERS = ("none", "gated")

#: Rows from which ``DiscoveryOptions(length=None)`` uses one length scale instead of a grid.
GRID_ROWS = 500

#: Random features of the cheap scorer that screens candidate parents (``DiscoveryOptions.screen``).
SCREEN_FEATURES = 8


@dataclass(frozen=True)
class DiscoveryOptions:
    """Search and scoring settings of :func:`discover`.

    Attributes:
        min_gain: smallest held-out gain (nats) for the search to add an edge.
        prune_nats: edges with a smaller held-out log-likelihood ratio are removed (<= min_gain).
        min_reverse: smallest held-out gain (nats) for the search to reverse an edge.
        max_parents: optional cap on |pa_i| during the search.
        max_moves: cap on the moves of each search phase.
        sparsify: ``"none"`` or ``"gated"`` (group-lasso MLP selection from all admissible
            parents consistent with the search order).
        features: random Fourier features M of the held-out scorer (:class:`CrossFitScorer`).
        ridge: ridge penalties on the feature weights to choose from.
        folds: cross-fitting folds K >= 2.
        length: RBF length scale(s) per sqrt(|P|) to choose from, in standard deviations; None:
            (0.7, 2.0) below ``GRID_ROWS`` rows (few rows orient more edges with the choice), else 1.0.
        floor: smallest residual variance, in standardised units.
        repeats: average the score over this many fold splits and feature draws
            (:class:`RepeatedScorer`); costs ``repeats`` times as much.
        gated: keyword arguments for :func:`inference.gated.select_parents` (keys in
            :data:`GATED_KWARGS`).
        bootstrap: number B of random subsamples (without replacement) the whole search is
            repeated on to measure edge stability; 0 for none. Costs B more searches.
        subsample: fraction of the rows in each subsample, in (0, 1).
        min_z: an edge is kept only if its held-out log-likelihood ratio is at least this many
            standard errors (across rows) above 0 (:mod:`inference.prune`); 0 turns the test off.
        transform: ``"auto"`` (normal scores of skewed or heavy-tailed columns),
            ``"rank"`` (of every column) or ``"none"`` (:mod:`inference.marginals`).
        screen: per addition step, the full scorer scores only this many candidate parents
            of a child, the best by a cheap scorer (8 random features); None scores all
            (:mod:`inference.search`).
    """

    min_gain: float = 10.0
    prune_nats: float = 5.0
    min_reverse: float = 1.0
    max_parents: int | None = None
    max_moves: int = 10_000
    sparsify: str = "none"
    features: int = 64
    ridge: float | Sequence[float] = (1e-3, 1e-2, 1e-1, 1.0)
    folds: int = 2
    length: float | Sequence[float] | None = None
    floor: float = 1e-6
    repeats: int = 1
    gated: Mapping[str, Any] | None = None
    bootstrap: int = 0
    subsample: float = 0.8
    min_z: float = 2.0
    transform: str = "auto"
    screen: int | None = 4

    def __post_init__(self) -> None:
        check_choice("sparsify", self.sparsify, SPARSIFIERS)
        min_gain = check_float("min_gain", self.min_gain)
        prune_nats = check_float("prune_nats", self.prune_nats)
        check_float("min_reverse", self.min_reverse)
        if not prune_nats <= min_gain:
            raise ValueError(f"prune_nats ({prune_nats}) must be <= min_gain ({min_gain})")
        if self.max_parents is not None:
            check_int("max_parents", self.max_parents, minimum=1)
        check_int("max_moves", self.max_moves, minimum=1)
        check_int("repeats", self.repeats, minimum=1)
        check_keywords("gated", self.gated, GATED_KWARGS)
        check_int("bootstrap", self.bootstrap, minimum=0)
        check_float("subsample", self.subsample, minimum=0.0, maximum=1.0, min_open=True, max_open=True)
        check_float("min_z", self.min_z, minimum=0.0)
        check_choice("transform", self.transform, TRANSFORMS)
        if self.screen is not None:
            check_int("screen", self.screen, minimum=1)

    def to_dict(self) -> dict[str, Any]:
        """JSON-compatible fields."""
        out = dict(self.__dict__)
        out["ridge"] = list(self.ridge) if isinstance(self.ridge, Sequence) else self.ridge
        out["length"] = (
            list(self.length) if isinstance(self.length, Sequence) else self.length
        )  # None: by rows
        out["gated"] = dict(self.gated) if self.gated else None
        return out


@dataclass(frozen=True)
class DiscoveryResult:
    """A learnt graph and its evidence.

    Attributes:
        graph: the learnt :class:`CausalGraph`; every edge carries a confidence in (0.5, 1]:
            sigmoid of its held-out log-likelihood ratio.
        log_ratio: edge -> held-out log-likelihood ratio Delta_ji (nats) against removing it.
        order: the topological order found by the search.
        history: the search moves, ``(move, parent, child, gain in nats)`` in the order
            taken; move is ``"add"``, ``"remove"`` or ``"reverse"``.
        score: held-out log-likelihood of the final graph, nats (sum over variables).
        evaluations: candidate parent sets scored.
        seconds: wall time.
        settings: the options and the intervened rows.
        cpdag: the Markov equivalence class of :attr:`graph` under the background knowledge
            (:func:`inference.equivalence.cpdag`): the edges the data cannot orient are undirected.
        stability: ``(parent, child)`` -> fraction of the ``bootstrap`` subsamples whose
            learnt graph has that directed edge (every edge found at least once); empty
            without ``bootstrap``.
        adjacency_stability: ``(a, b)`` (declaration order) -> fraction of subsamples with
            an edge between a and b either way.
        z: edge -> its held-out log-likelihood ratio in standard errors (:mod:`inference.prune`;
            inf for a required edge or with ``min_z = 0``).
    """

    graph: CausalGraph
    log_ratio: dict[tuple[str, str], float]
    order: tuple[str, ...]
    history: tuple[tuple[str, str, str, float], ...]
    score: float
    evaluations: int
    seconds: float
    settings: dict[str, Any] = field(default_factory=dict)
    cpdag: CPDAG | None = None
    stability: dict[tuple[str, str], float] = field(default_factory=dict)
    adjacency_stability: dict[tuple[str, str], float] = field(default_factory=dict)
    z: dict[tuple[str, str], float] = field(default_factory=dict)

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
                    "stability": self.stability.get((p, c)),
                    "z": _finite(self.z.get((p, c))),
                }
                for p, c in self.graph.edges
            ],
            "cpdag": None if self.cpdag is None else self.cpdag.to_dict(),
            "stability": [[p, c, v] for (p, c), v in self.stability.items()],
            "adjacency_stability": [[a, b, v] for (a, b), v in self.adjacency_stability.items()],
            "order": list(self.order),
            "history": [list(h) for h in self.history],
            "score": self.score,
            "evaluations": self.evaluations,
            "seconds": self.seconds,
            "settings": dict(self.settings),
        }


def shd(learnt: Any, truth: Any) -> int:
    """Structural Hamming distance (:mod:`inference.equivalence` documents the counting).

    DAG against DAG: missing + extra edges, a reversed edge counting once. When either side
    is a :class:`inference.equivalence.CPDAG`, every pair whose state (absent, either
    direction, undirected) differs counts 1, so an undirected edge against a directed one
    counts 1. A reference given as ``(parent, child)`` pairs may be cyclic; a reference
    2-cycle is matched by a learnt edge either way (:func:`inference.equivalence.compare_edges`).

    Args:
        learnt: a graph, a CPDAG or a sequence of ``(parent, child)`` name pairs.
        truth: the reference, in the same forms.
    """
    if isinstance(learnt, CPDAG) or isinstance(truth, CPDAG):
        a = learnt.states() if isinstance(learnt, CPDAG) else _states(learnt, "learnt")
        b = truth.states() if isinstance(truth, CPDAG) else _states(truth, "truth")
        return sum(a.get(k) != b.get(k) for k in set(a) | set(b))
    return compare_edges(learnt, truth).shd


def _states(graph: Any, what: str) -> dict[frozenset[str], Any]:
    edges = graph.edges if isinstance(graph, CausalGraph) else check_edges(what, graph)
    return {frozenset(e): tuple(e) for e in edges}


def _resolved(opts: DiscoveryOptions, n: int) -> DiscoveryOptions:
    """``opts`` with ``length=None`` replaced by the grid for ``n`` rows (the settings record it)."""
    return opts if opts.length is not None else replace(opts, length=(0.7, 2.0) if n < GRID_ROWS else (1.0,))


def _finite(x: float | None) -> float | None:
    """``x`` for JSON: None when it is absent or not finite."""
    return x if x is not None and math.isfinite(x) else None


def sigmoid(x: float) -> float:
    """Logistic function ``1 / (1 + exp(-x))`` without overflow; 1 at inf and 0 at -inf."""
    if x >= 0:
        return 1.0 / (1.0 + math.exp(-x))
    e = math.exp(x)
    return e / (1.0 + e)


def _options(options: Any) -> DiscoveryOptions:
    if options is None:
        return DiscoveryOptions()
    if not isinstance(options, DiscoveryOptions):
        raise ValueError(f"options must be a DiscoveryOptions, got {type(options).__name__}")
    return options


def _inputs(variables: Any, data: Any) -> tuple[list[Any], Mapping[str, Any]]:
    """The variables and name -> ``(N, dim)`` columns from the two forms of the first arguments."""
    if data is None:
        if isinstance(variables, CausalGraph) or (
            isinstance(variables, Sequence) and not isinstance(variables, (str, bytes, np.ndarray))
        ):
            raise ValueError("data is missing: call discover(table) or discover(variables, data)")
        table = as_table(variables)
        return table.variables(), table.values
    vs = as_variables(variables)
    if is_table(data):
        table = as_table(data, keep={v.name for v in vs})
        missing = [v.name for v in vs if v.name not in table]
        if missing:
            raise ValueError(
                f"the table has no columns for variables {missing}; columns: {list(table.names)}"
            )
        return vs, table.values
    return vs, data


def _search(
    vs: Sequence[Any],
    sdata: StructureData,
    allowed: Mapping[str, tuple[str, ...]],
    required: set[tuple[str, str]],
    opts: DiscoveryOptions,
    seed: int,
    bar: Any,
) -> tuple[CausalGraph, dict[tuple[str, str], float], tuple[str, ...], list[Any], float, int, dict]:
    """One search, sparsification and pruning on ``sdata``; the last item is edge -> z."""
    scorer = RepeatedScorer(
        sdata,
        repeats=opts.repeats,
        features=opts.features,
        ridge=opts.ridge,
        folds=opts.folds,
        length=opts.length,
        floor=opts.floor,
        seed=seed,
    )
    scores = LocalScores(scorer)
    screen = None
    if opts.screen is not None and opts.features > SCREEN_FEATURES:
        cheap = CrossFitScorer(
            sdata,
            features=SCREEN_FEATURES,
            ridge=0.1,
            folds=opts.folds,
            length=1.0,
            floor=opts.floor,
            seed=seed,
        )
        screen = (LocalScores(cheap), opts.screen)
    dag = Dag(sdata.names)
    for p, c in sorted(required, key=lambda e: (dag.index[e[1]], dag.index[e[0]])):
        dag.add(p, c)
    history = hill_climb(
        scores,
        allowed,
        dag,
        min_gain=opts.min_gain,
        prune_nats=opts.prune_nats,
        min_reverse=opts.min_reverse,
        max_parents=opts.max_parents,
        required=required,
        max_moves=opts.max_moves,
        screen=screen,
        on_move=None
        if bar is None
        else lambda m: bar.set_description_str(f"discover: {m[0]} {m[1]} -> {m[2]}"),
    )
    order = dag.order()
    parents = {n: list(ps) for n, ps in dag.parents.items()}
    if opts.sparsify == "gated":
        from inference.gated import select_parents

        position = {n: k for k, n in enumerate(order)}
        candidates = {c: tuple(p for p in allowed[c] if position[p] < position[c]) for c in sdata.names}
        chosen = select_parents(sdata, candidates, seed=seed, **dict(opts.gated or {}))
        parents = {
            c: sorted({*chosen[c], *(p for p, cc in required if cc == c)}, key=dag.index.__getitem__)
            for c in sdata.names
        }
    ratios, zs, total = prune(scores, parents, dag.index, opts.prune_nats, required, opts.min_z)
    edges = [(p, c) for c in sdata.names for p in parents[c]]
    graph = CausalGraph(vs, edges, {e: sigmoid(ratios[e]) for e in edges})
    return graph, {e: float(ratios[e]) for e in edges}, order, history, float(total), scorer.calls, zs


def discover(
    variables: Any,
    data: Any = None,
    *,
    intervened: Mapping[str, Any] | None = None,
    tiers: Sequence[Sequence[str]] | None = None,
    forbidden: Iterable[tuple[str, str]] = (),
    required: Iterable[tuple[str, str]] = (),
    options: DiscoveryOptions | None = None,
    seed: int = 0,
    progress_bar: bool = False,
) -> DiscoveryResult:
    """Learn the parent sets of the world model from data.

    Two forms: ``discover(table)`` learns over every column of a table (a pandas
    DataFrame, a :class:`models.tables.Table`, a mapping label -> ``(N,)`` array, or a
    structured array), each an observed scalar variable named by the table's name rule
    (:mod:`models.tables`); ``discover(variables, data)`` learns over given variables.

    Args:
        variables: a table (then ``data`` is None), a :class:`CausalGraph` (its edges are
            ignored) or a list of ``Variable``.
        data: name -> ``(N, dim)`` values of every variable, or a table holding a column
            for each; each column is standardised on its non-intervened rows first.
        intervened: name -> ``(N,)`` bool, True where the variable was set by ``do``;
            those rows do not enter that variable's mechanism likelihood. Actions need no
            mask: they are roots.
        tiers: optional ordered groups of names; a parent must be in the same or an earlier
            tier (:func:`admissible_parents`).
        forbidden: ``(parent, child)`` edges that may not appear.
        required: ``(parent, child)`` edges that must appear.
        options: :class:`DiscoveryOptions` (search, scorer, stability subsamples).
        seed: seeds the folds, the random features, the gated MLPs and the subsamples.
        progress_bar: show tqdm bars over the search moves and the subsamples.

    Returns:
        :class:`DiscoveryResult`: the DAG with edge confidences, its CPDAG, and with
        ``options.bootstrap`` the edge stabilities.

    Raises:
        ValueError: bad variables, data, masks or background knowledge (unknown names,
            non-float columns, wrong shapes, NaN, fewer than 8 rows), or a setting of the
            wrong type or range.
    """
    start = time.perf_counter()
    opts = _options(options)
    seed = check_seed("seed", seed)
    progress_bar = check_bool("progress_bar", progress_bar)
    vs, data = _inputs(variables, data)
    required = set(check_edges("required", required))
    allowed = admissible_parents(vs, tiers=tiers, forbidden=forbidden, required=required)
    data, transformed = transform_columns(data, opts.transform) if isinstance(data, Mapping) else (data, ())
    sdata = StructureData.build(vs, data, intervened)
    opts = _resolved(opts, sdata.n)
    bar = tqdm(desc="discover", disable=not progress_bar, leave=False, bar_format="{desc} [{elapsed}]")
    try:
        graph, ratios, order, history, total, calls, zs = _search(
            vs, sdata, allowed, required, opts, seed, bar
        )
    finally:
        bar.close()
    stability, adjacency = edge_stability(vs, sdata, allowed, required, opts, seed, progress_bar, _search)
    seconds = time.perf_counter() - start
    log.info(
        "discover: %d edges over %d variables in %.2f s (%d sets scored)",
        len(ratios),
        len(vs),
        seconds,
        calls,
    )
    settings = {
        **opts.to_dict(),
        "seed": seed,
        "intervened_rows": {k: int((~v).sum()) for k, v in sdata.rows.items() if not bool(v.all())},
        "transformed": list(transformed),
    }
    dag = cpdag(graph, allowed=allowed, required=required)
    return DiscoveryResult(
        graph, ratios, order, tuple(history), total, calls, seconds, settings, dag, stability, adjacency, zs
    )
