"""Peer structure learners from causal-learn (GRaSP, PC), used only when it is importable.

causal-learn is optional (not a dependency of pal). Both peers return a CPDAG: directed
edges plus undirected ones. :func:`cpdag_shd` compares a CPDAG with the true DAG pair by
pair: a missing, extra, reversed *or undirected* adjacency counts 1 (an undirected edge is
an orientation the method did not commit to); ``undirected_cost=0`` gives the optimistic
reading in which an undirected true edge counts as right. :func:`compare` runs a peer on
standardised data and scores it against the true graph.
"""

from __future__ import annotations

import importlib.util
import random
import time
from collections.abc import Iterable, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import numpy as np

from models import CausalGraph

__all__ = ["PEERS", "PeerGraph", "available", "compare", "cpdag_shd", "run_peer", "warm_up"]

PEERS = ("grasp", "pc")


@dataclass(frozen=True)
class PeerGraph:
    """A CPDAG from a peer: directed ``(parent, child)`` pairs and undirected pairs (sorted names)."""

    directed: frozenset[tuple[str, str]]
    undirected: frozenset[tuple[str, str]]
    seconds: float


def available() -> bool:
    """True when causal-learn can be imported."""
    return importlib.util.find_spec("causallearn") is not None


@contextmanager
def _seeded(seed: int) -> Any:
    """Seed numpy's and Python's global generators for the call, then restore them.

    causal-learn draws from both (GRaSP shuffles with ``random``).
    """
    np_state, py_state = np.random.get_state(), random.getstate()
    np.random.seed(seed)
    random.seed(seed)
    try:
        yield
    finally:
        np.random.set_state(np_state)
        random.setstate(py_state)


def _from_general_graph(adj: np.ndarray, names: Sequence[str]) -> tuple[set, set]:
    directed, undirected = set(), set()
    d = len(names)
    for i in range(d):
        for j in range(i + 1, d):
            a, b = adj[i, j], adj[j, i]
            if a == 0 and b == 0:
                continue
            if a == -1 and b == 1:
                directed.add((names[i], names[j]))
            elif a == 1 and b == -1:
                directed.add((names[j], names[i]))
            else:  # -1/-1 undirected; anything else (bidirected) is left unoriented
                undirected.add(tuple(sorted((names[i], names[j]))))
    return directed, undirected


def run_peer(
    method: str, x: np.ndarray, names: Sequence[str], *, seed: int = 0, alpha: float = 0.01
) -> PeerGraph:
    """Run GRaSP (BIC score) or PC (Fisher-z, level ``alpha``) on ``x`` (N, d).

    Raises:
        ValueError: unknown method, or causal-learn is not installed.
    """
    if method not in PEERS:
        raise ValueError(f"peer {method!r} unknown; expected one of {PEERS}")
    if not available():
        raise ValueError("causal-learn is not installed; install it to compare with GRaSP and PC")
    x = np.asarray(x, dtype=float)
    if x.ndim != 2 or x.shape[1] != len(names):
        raise ValueError(f"x has shape {x.shape}, expected (N, {len(names)})")
    start = time.perf_counter()
    with _seeded(seed):
        if method == "grasp":
            from causallearn.search.PermutationBased.GRaSP import grasp

            adj = grasp(x, score_func="local_score_BIC_from_cov", verbose=False).graph
        else:
            from causallearn.search.ConstraintBased.PC import pc

            adj = pc(x, alpha=alpha, indep_test="fisherz", show_progress=False).G.graph
    directed, undirected = _from_general_graph(np.asarray(adj), list(names))
    return PeerGraph(frozenset(directed), frozenset(undirected), time.perf_counter() - start)


def cpdag_shd(
    directed: Iterable[tuple[str, str]],
    undirected: Iterable[tuple[str, str]],
    truth: Iterable[tuple[str, str]],
    undirected_cost: float = 1.0,
) -> float:
    """SHD of a CPDAG against a DAG; every pair whose state differs counts 1.

    An undirected edge where the DAG has an edge (either way) counts ``undirected_cost``
    (1: the method did not commit to the orientation; 0: the optimistic reading that any
    orientation consistent with the CPDAG is right).
    """
    state: dict[frozenset, Any] = {}
    for p, c in directed:
        state[frozenset((p, c))] = (p, c)
    for p, c in undirected:
        state[frozenset((p, c))] = "undirected"
    true: Mapping[frozenset, Any] = {frozenset(e): tuple(e) for e in truth}
    total = 0.0
    for k in set(state) | set(true):
        got, want = state.get(k), true.get(k)
        if got == want:
            continue
        total += undirected_cost if got == "undirected" and want is not None else 1.0
    return int(total) if float(total).is_integer() else total


def warm_up() -> None:
    """Run every peer once on 50 x 3 noise, so that imports and first-call costs stay out of timings."""
    noise = np.random.default_rng(0).normal(size=(50, 3))
    for method in PEERS:
        run_peer(method, noise, ["a", "b", "c"], seed=0)


def compare(
    method: str, data: Mapping[str, np.ndarray], truth: CausalGraph, *, seed: int = 0
) -> dict[str, Any]:
    """Run peer ``method`` on ``data`` (name -> ``(N, 1)``, standardised) and score it against ``truth``.

    Returns:
        ``shd`` (an undirected edge counts 1), ``shd_undirected_free`` (it counts 0), ``edges``
        (directed + undirected), ``undirected`` and ``seconds`` of the call.
    """
    names = truth.names
    g = run_peer(method, np.concatenate([data[k] for k in names], 1), names, seed=seed)
    return {
        "shd": cpdag_shd(g.directed, g.undirected, truth.edges),
        "shd_undirected_free": cpdag_shd(g.directed, g.undirected, truth.edges, undirected_cost=0.0),
        "edges": len(g.directed) + len(g.undirected),
        "undirected": len(g.undirected),
        "seconds": g.seconds,
    }
