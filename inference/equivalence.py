"""Markov equivalence classes (CPDAGs) and comparisons with reference graphs, cyclic ones included.

Observational data identify a DAG only up to its Markov equivalence class. The class is
drawn as a CPDAG: an edge is *directed* when every DAG of the class orients it the same way
(it is compelled), and *undirected* otherwise. :func:`cpdag` finds it from a DAG: orient the
v-structures ``a -> c <- b`` (a, b not adjacent) and the edges that background knowledge
fixes (an edge whose reverse is not admissible, e.g. out of an action or forward in time,
and required edges), then apply Meek's rules R1-R4 until nothing changes (Meek 1995).

Structural Hamming distance, as :func:`shd` counts it:

* DAG against DAG: missing + extra edges, a reversed edge counting once (not twice).
* When either side is a :class:`CPDAG`: every unordered pair whose state differs counts 1,
  the states being absent, ``a -> b``, ``b -> a`` and undirected. So an undirected edge where
  the other graph has a directed one counts 1 (an orientation not committed to), and a
  reversed edge counts 1.

A reference graph may be cyclic (published consensus networks often hold feedback loops,
which no DAG and no :class:`models.CausalGraph` can): pass it as a list of ``(parent,
child)`` pairs to :func:`compare_edges` (or :func:`shd`). There, a reference 2-cycle
``a <-> b`` is one adjacency that a learnt edge either way (or undirected) matches, and its
missing second direction is not counted; every other reference edge is compared on its own.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from models.checks import check_edges
from models.graph import CausalGraph

__all__ = ["CPDAG", "EdgeComparison", "compare_edges", "cpdag"]


@dataclass(frozen=True)
class CPDAG:
    """A completed partially directed graph: compelled and reversible edges of one class.

    Attributes:
        names: the variables, in declaration order.
        directed: compelled ``(parent, child)`` edges.
        undirected: reversible edges as ``(a, b)`` pairs, ``a`` declared before ``b``.
    """

    names: tuple[str, ...]
    directed: tuple[tuple[str, str], ...]
    undirected: tuple[tuple[str, str], ...]

    def to_dict(self) -> dict[str, Any]:
        """JSON-compatible form."""
        return {
            "names": list(self.names),
            "directed": [list(e) for e in self.directed],
            "undirected": [list(e) for e in self.undirected],
        }

    def states(self) -> dict[frozenset[str], Any]:
        """Unordered pair -> ``(parent, child)`` or ``"undirected"``, for the adjacent pairs."""
        out: dict[frozenset[str], Any] = {frozenset(e): tuple(e) for e in self.directed}
        out.update({frozenset(e): "undirected" for e in self.undirected})
        return out


def cpdag(
    graph: CausalGraph | Iterable[tuple[str, str]],
    names: Sequence[str] | None = None,
    *,
    allowed: Mapping[str, Sequence[str]] | None = None,
    required: Iterable[tuple[str, str]] = (),
) -> CPDAG:
    """The CPDAG (equivalence class) of a DAG, with optional background knowledge.

    Args:
        graph: a :class:`models.CausalGraph` or ``(parent, child)`` pairs of a DAG.
        names: the variables when ``graph`` is a list of pairs (default: those named).
        allowed: child -> admissible parents (:func:`inference.admissible_parents`); an
            edge whose reverse is not admissible is compelled. Default for a CausalGraph:
            edges out of actions and from lag 1 to lag 0 are compelled.
        required: edges known to be present as given (compelled).

    Returns:
        :class:`CPDAG`.

    Raises:
        ValueError: malformed edges or a cycle.
    """
    if isinstance(graph, CausalGraph):
        order = list(graph.names)
        edges = list(graph.edges)
        if allowed is None:
            from inference.admissible import admissible_parents

            allowed = admissible_parents(graph)
    else:
        edges = list(check_edges("graph", graph))
        order = list(names) if names is not None else list(dict.fromkeys(n for e in edges for n in e))
    index = {n: i for i, n in enumerate(order)}
    unknown = sorted({n for e in edges for n in e} - set(index))
    if unknown:
        raise ValueError(f"edges name {unknown}, which are not among the variables {order}")
    parents: dict[str, set[str]] = {n: set() for n in order}
    for p, c in edges:
        parents[c].add(p)
    adj = {n: set() for n in order}
    for p, c in edges:
        adj[p].add(c)
        adj[c].add(p)
    directed: set[tuple[str, str]] = set()
    for c in order:  # v-structures
        ps = sorted(parents[c], key=index.__getitem__)
        for i, a in enumerate(ps):
            for b in ps[i + 1 :]:
                if b not in adj[a]:
                    directed |= {(a, c), (b, c)}
    known = set(check_edges("required", required))
    for p, c in edges:
        if (p, c) in known or (allowed is not None and c not in allowed.get(p, ())):
            directed.add((p, c))  # required, or the reverse c -> p is not admissible
    undirected = {(p, c) for p, c in edges if (p, c) not in directed}
    _meek(undirected, directed, adj)
    pairs = [(p, c) if index[p] < index[c] else (c, p) for p, c in undirected]
    return CPDAG(
        tuple(order),
        tuple(sorted(directed, key=lambda e: (index[e[1]], index[e[0]]))),
        tuple(sorted(pairs, key=lambda e: (index[e[0]], index[e[1]]))),
    )


def _meek(
    undirected: set[tuple[str, str]], directed: set[tuple[str, str]], adj: Mapping[str, set[str]]
) -> None:
    """Apply Meek's rules R1-R4 in place; ``undirected`` holds each reversible edge once."""

    def und(a: str, b: str) -> bool:
        return (a, b) in undirected or (b, a) in undirected

    def orient(a: str, b: str) -> None:
        undirected.discard((a, b))
        undirected.discard((b, a))
        directed.add((a, b))

    changed = True
    while changed:
        changed = False
        for e in list(undirected):
            for a, b in (e, e[::-1]):
                if not und(a, b):
                    break
                into_a = {p for p, c in directed if c == a}
                into_b = {p for p, c in directed if c == b}
                out_a = {c for p, c in directed if p == a}
                # R1: c -> a - b, c and b not adjacent => a -> b
                r1 = any(c not in adj[b] and c != b for c in into_a)
                # R2: a -> c -> b and a - b => a -> b
                r2 = bool(out_a & into_b)
                # R3: a - c -> b, a - d -> b, c and d not adjacent => a -> b
                cands = [c for c in into_b if und(a, c)]
                r3 = any(d not in adj[c] for i, c in enumerate(cands) for d in cands[i + 1 :])
                # R4: a - c, c -> d -> b, a adjacent d, c and b not adjacent => a -> b
                r4 = any(
                    und(a, c) and c not in adj[b] and d in adj[a]
                    for c in adj[a]
                    for d in {q for p, q in directed if p == c}
                    if (d, b) in directed
                )
                if r1 or r2 or r3 or r4:
                    orient(a, b)
                    changed = True
                    break


@dataclass(frozen=True)
class EdgeComparison:
    """A learnt graph against a reference graph that may be cyclic (module docstring).

    Attributes:
        correct: learnt directed edges the reference has in that direction (or as a 2-cycle).
        reversed: learnt edges the reference has only the other way.
        undirected: learnt undirected edges where the reference has an edge (not a 2-cycle).
        extra: learnt adjacencies the reference does not have.
        missing: reference adjacencies the learnt graph does not have.
        two_cycles: reference pairs with edges both ways.
    """

    correct: tuple[tuple[str, str], ...]
    reversed: tuple[tuple[str, str], ...]
    undirected: tuple[tuple[str, str], ...]
    extra: tuple[tuple[str, str], ...]
    missing: tuple[tuple[str, str], ...]
    two_cycles: tuple[tuple[str, str], ...]

    @property
    def shd(self) -> int:
        """Missing + extra + reversed + undirected: every pair whose state differs counts 1."""
        return len(self.missing) + len(self.extra) + len(self.reversed) + len(self.undirected)

    @property
    def precision(self) -> float:
        """Correctly oriented learnt edges / learnt adjacencies (nan without any)."""
        learnt = len(self.correct) + len(self.reversed) + len(self.undirected) + len(self.extra)
        return len(self.correct) / learnt if learnt else float("nan")

    @property
    def recall(self) -> float:
        """Correctly oriented learnt edges / reference adjacencies (nan without any)."""
        ref = len(self.correct) + len(self.reversed) + len(self.undirected) + len(self.missing)
        return len(self.correct) / ref if ref else float("nan")

    @property
    def skeleton_recall(self) -> float:
        """Reference adjacencies found in any orientation / reference adjacencies."""
        ref = len(self.correct) + len(self.reversed) + len(self.undirected) + len(self.missing)
        return (ref - len(self.missing)) / ref if ref else float("nan")

    def to_dict(self) -> dict[str, Any]:
        """JSON-compatible counts, rates and edge lists."""
        out: dict[str, Any] = {k: [list(e) for e in getattr(self, k)] for k in self.__dataclass_fields__}
        out |= {"shd": self.shd, "precision": self.precision, "recall": self.recall}
        return out | {"skeleton_recall": self.skeleton_recall}


def _learnt_states(learnt: Any) -> dict[frozenset[str], Any]:
    if isinstance(learnt, CPDAG):
        return learnt.states()
    if isinstance(learnt, CausalGraph):
        return {frozenset(e): e for e in learnt.edges}
    out: dict[frozenset[str], Any] = {}
    for e in check_edges("learnt", learnt):
        key = frozenset(e)
        if key in out and out[key] != e:
            raise ValueError(
                f"learnt has both {e[1]!r} -> {e[0]!r} and {e[0]!r} -> {e[1]!r}; pass a DAG or a CPDAG"
            )
        out[key] = e
    return out


def compare_edges(learnt: Any, reference: CausalGraph | Iterable[tuple[str, str]]) -> EdgeComparison:
    """Compare a learnt DAG or CPDAG with a reference graph, which may have cycles.

    Args:
        learnt: a :class:`models.CausalGraph`, a :class:`CPDAG` or ``(parent, child)`` pairs.
        reference: a CausalGraph or ``(parent, child)`` pairs; cycles (2-cycles too) allowed.

    Returns:
        :class:`EdgeComparison` (module docstring for how each pair counts).

    Raises:
        ValueError: malformed edges, or learnt pairs given both ways.
    """
    ref_edges = set(
        reference.edges if isinstance(reference, CausalGraph) else check_edges("reference", reference)
    )
    ref: dict[frozenset[str], set[tuple[str, str]]] = {}
    for e in ref_edges:
        ref.setdefault(frozenset(e), set()).add(e)
    got = _learnt_states(learnt)
    correct, rev, und, extra, missing = [], [], [], [], []
    two = sorted(tuple(sorted(k)) for k, es in ref.items() if len(es) == 2)
    for key, state in got.items():
        want = ref.get(key)
        pair = tuple(sorted(key))
        if want is None:
            extra.append(state if state != "undirected" else pair)
        elif len(want) == 2:
            correct.append(state if state != "undirected" else pair)
        elif state == "undirected":
            und.append(next(iter(want)))
        elif state in want:
            correct.append(state)
        else:
            rev.append(state)
    missing = [next(iter(es)) if len(es) == 1 else tuple(sorted(k)) for k, es in ref.items() if k not in got]
    return EdgeComparison(
        tuple(sorted(correct)),
        tuple(sorted(rev)),
        tuple(sorted(und)),
        tuple(sorted(extra)),
        tuple(sorted(missing)),
        tuple(two),  # type: ignore[arg-type]
    )
