"""CPDAGs against brute-force enumeration of the Markov equivalence class; SHD and cyclic references."""

from __future__ import annotations

import itertools

import networkx as nx
import numpy as np
import pytest

from inference.discovery import shd
from inference.equivalence import CPDAG, compare_edges, cpdag
from models import CausalGraph, Variable


def _vstructures(edges):
    parents = {}
    for p, c in edges:
        parents.setdefault(c, set()).add(p)
    adj = {frozenset(e) for e in edges}
    return {
        (min(a, b), c, max(a, b))
        for c, ps in parents.items()
        for a, b in itertools.combinations(sorted(ps), 2)
        if frozenset((a, b)) not in adj
    }


def brute_force_class(names, edges):
    """Every DAG with the same skeleton and v-structures (Verma and Pearl 1990)."""
    skeleton = [tuple(e) for e in edges]
    target = _vstructures(edges)
    members = []
    for flips in itertools.product((False, True), repeat=len(skeleton)):
        cand = [(c, p) if f else (p, c) for (p, c), f in zip(skeleton, flips, strict=True)]
        g = nx.DiGraph(cand)
        g.add_nodes_from(names)
        if nx.is_directed_acyclic_graph(g) and _vstructures(cand) == target:
            members.append(set(cand))
    return members


def random_dag(d, p, rng):
    order = list(rng.permutation(d))
    names = [f"v{i}" for i in range(d)]
    edges = [
        (names[order[i]], names[order[j]]) for i in range(d) for j in range(i + 1, d) if rng.random() < p
    ]
    return names, edges


@pytest.mark.parametrize("seed", range(25))
def test_cpdag_matches_the_enumerated_equivalence_class(seed):
    rng = np.random.default_rng(seed)
    names, edges = random_dag(int(rng.integers(3, 7)), 0.5, rng)
    members = brute_force_class(names, edges)
    compelled = {e for e in edges if all(e in m for m in members)}
    got = cpdag(edges, names)
    assert set(got.directed) == compelled
    assert {frozenset(e) for e in got.undirected} == {frozenset(e) for e in edges if e not in compelled}


def test_background_knowledge_orients_edges_out_of_actions():
    g = CausalGraph(
        [Variable("a", "action", bounds=(-1, 1)), Variable("x", "observed"), Variable("y", "observed")],
        [("a", "x"), ("x", "y")],
    )
    # without knowledge a chain's class is fully undirected; the action must be a root, and then R1 orients x -> y
    assert cpdag(g.edges, g.names).directed == ()
    assert cpdag(g).directed == (("a", "x"), ("x", "y"))
    assert cpdag(g.edges, g.names, required=[("x", "y")]).directed == (("x", "y"),)


def test_shd_counting_rules():
    truth = [("a", "b"), ("b", "c")]
    assert shd([("a", "b"), ("b", "c")], truth) == 0
    assert shd([("b", "a"), ("b", "c")], truth) == 1  # a reversed edge counts once
    assert shd([("a", "b")], truth) == 1  # missing
    assert shd([("a", "b"), ("b", "c"), ("a", "c")], truth) == 1  # extra
    class_ = CPDAG(("a", "b", "c"), (), (("a", "b"), ("b", "c")))
    assert shd(class_, truth) == 2  # each undirected edge against a directed one counts 1
    assert shd(class_, cpdag(truth)) == 0  # the same class


def test_compare_edges_against_a_cyclic_reference():
    reference = [("a", "b"), ("b", "a"), ("b", "c"), ("c", "d"), ("d", "b")]  # a 2-cycle and a 3-cycle
    with pytest.raises(ValueError, match="cycle"):
        CausalGraph.from_edges(reference)
    learnt = CausalGraph.from_edges([("b", "a"), ("c", "b"), ("c", "d")])
    cmp = compare_edges(learnt, reference)
    assert cmp.two_cycles == (("a", "b"),)
    assert cmp.correct == (("b", "a"), ("c", "d"))  # either direction matches the 2-cycle
    assert cmp.reversed == (("c", "b"),)
    assert cmp.missing == (("d", "b"),)
    assert cmp.extra == () and cmp.shd == 2 == shd(learnt, reference)
    assert cmp.precision == pytest.approx(2 / 3) and cmp.recall == pytest.approx(2 / 4)
    assert cmp.skeleton_recall == pytest.approx(3 / 4)
    assert cmp.to_dict()["shd"] == 2
    with pytest.raises(ValueError, match="both"):
        compare_edges([("a", "b"), ("b", "a")], reference)
