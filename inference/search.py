"""Score-based DAG search over admissible edges (the search step of :mod:`inference.discovery`).

The score is decomposable, log L(G) = sum_i S_i(pa_i) (:mod:`inference.crossfit`), so a
move changes only the local scores of the children it touches. Moves and their gains:

    add j -> i:      S_i(pa_i + j) - S_i(pa_i)                            (taken if > min_gain)
    remove j -> i:   S_i(pa_i - j) - S_i(pa_i)                            (taken if > -prune_nats)
    reverse j -> i:  S_i(pa_i - j) - S_i(pa_i) + S_j(pa_j + i) - S_j(pa_j) (taken if > min_reverse)

Phase 1 adds greedily (CAM-style) until no addition gains ``min_gain``. Phase 2 hill-climbs
with all three moves, best first, so that an edge oriented wrongly early in phase 1 (and the
extra edges that compensated for it) can be repaired. Every move keeps the graph acyclic
and admissible. Local scores are cached by (child, parent set).

With ``screen = k``, an addition step scores every candidate parent of a child with a cheap
scorer first (fewer random features) and gives only its k best to the full scorer; the other
candidates are taken as gaining nothing at that step. Most candidates of a sparse graph are
irrelevant, so this cuts the full scorer's calls by about d / k.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

from torch import Tensor

from inference.crossfit import CrossFitScorer, RepeatedScorer

__all__ = ["Dag", "LocalScores", "hill_climb", "kahn_order"]


def kahn_order(names: Sequence[str], parents: Mapping[str, Sequence[str]]) -> tuple[str, ...]:
    """A topological order, ties broken by declaration order."""
    left = {n: set(parents[n]) for n in names}
    out: list[str] = []
    while left:
        ready = [n for n in names if n in left and not left[n]]
        if not ready:
            raise ValueError(f"parent sets contain a cycle among {sorted(left)}")
        out.append(ready[0])
        del left[ready[0]]
        for ps in left.values():
            ps.discard(ready[0])
    return tuple(out)


class Dag:
    """Parent sets with an ancestor relation for cycle checks."""

    def __init__(self, names: Sequence[str]) -> None:
        self.names = tuple(names)
        self.index = {n: i for i, n in enumerate(names)}
        self.parents: dict[str, tuple[str, ...]] = {n: () for n in names}
        self.ancestors: dict[str, set[str]] = {n: set() for n in names}

    def creates_cycle(self, parent: str, child: str) -> bool:
        """Whether adding the edge ``parent -> child`` would close a cycle."""
        return parent == child or child in self.ancestors[parent]

    def sorted(self, names: set[str] | Sequence[str]) -> tuple[str, ...]:
        """The distinct ``names`` in declaration order."""
        return tuple(sorted(set(names), key=self.index.__getitem__))

    def add(self, parent: str, child: str) -> None:
        """Add the edge ``parent -> child`` and update the ancestors; raises ValueError on a cycle."""
        if self.creates_cycle(parent, child):
            raise ValueError(f"edge {parent!r} -> {child!r} would close a cycle")
        self.parents[child] = self.sorted({*self.parents[child], parent})
        new = self.ancestors[parent] | {parent}
        for k in self.names:
            if k == child or child in self.ancestors[k]:
                self.ancestors[k] |= new

    def remove(self, parent: str, child: str) -> None:
        """Remove the edge ``parent -> child`` and recompute the ancestors."""
        self.parents[child] = tuple(p for p in self.parents[child] if p != parent)
        self._recompute()

    def _recompute(self) -> None:
        anc: dict[str, set[str]] = {}
        for n in kahn_order(self.names, self.parents):
            anc[n] = set()
            for p in self.parents[n]:
                anc[n] |= anc[p] | {p}
        self.ancestors = anc

    def other_path(self, parent: str, child: str) -> bool:
        """Is there a directed path parent -> ... -> child besides the edge itself?"""
        children: dict[str, list[str]] = {n: [] for n in self.names}
        for c in self.names:
            for p in self.parents[c]:
                if (p, c) != (parent, child):
                    children[p].append(c)
        stack, seen = list(children[parent]), set()
        while stack:
            n = stack.pop()
            if n == child:
                return True
            if n not in seen:
                seen.add(n)
                stack.extend(children[n])
        return False

    def edges(self) -> list[tuple[str, str]]:
        """All ``(parent, child)`` edges, grouped by child in declaration order."""
        return [(p, c) for c in self.names for p in self.parents[c]]

    def order(self) -> tuple[str, ...]:
        """A topological order of the names (see :func:`kahn_order`)."""
        return kahn_order(self.names, self.parents)


class LocalScores:
    """Cached S_i(P), batched by total input dim."""

    def __init__(self, scorer: CrossFitScorer | RepeatedScorer) -> None:
        self.scorer = scorer
        self.cache: dict[tuple[str, tuple[str, ...]], float] = {}
        self.rows_cache: dict[tuple[str, tuple[str, ...]], Tensor] = {}

    def many(self, child: str, sets: Sequence[tuple[str, ...]]) -> list[float]:
        """S_child(P) in nats for each parent set P in ``sets``, scoring only uncached sets."""
        todo = [s for s in dict.fromkeys(sets) if (child, s) not in self.cache]
        groups: dict[int, list[tuple[str, ...]]] = {}
        for s in todo:
            groups.setdefault(len(self.scorer.data.columns(s)), []).append(s)
        for batch in groups.values():
            score, rows = self.scorer.score_rows(child, batch)
            for s, v, r in zip(batch, score.tolist(), rows, strict=True):
                self.cache[child, s] = v
                self.rows_cache[child, s] = r
        return [self.cache[child, s] for s in sets]

    def one(self, child: str, parents: tuple[str, ...]) -> float:
        """S_child(parents) in nats (cached)."""
        return self.many(child, [parents])[0]

    def rows(self, child: str, parents: tuple[str, ...]) -> Tensor:
        """Per-row held-out log-likelihoods ``(n_i,)`` nats of S_child(parents) (cached); they sum to it."""
        self.many(child, [parents])
        return self.rows_cache[child, parents]


def _screened(
    screen: tuple[LocalScores, int], dag: Dag, child: str, ps: tuple[str, ...], cands: list[str]
) -> list[str]:
    """The k candidate parents of ``child`` with the largest cheap gains (ties: declaration order)."""
    cheap, k = screen
    gains = cheap.many(child, [dag.sorted({*ps, p}) for p in cands])
    return [p for _, p in sorted(zip(gains, cands, strict=True), key=lambda t: -t[0])[:k]]


def hill_climb(
    scores: LocalScores,
    allowed: Mapping[str, tuple[str, ...]],
    dag: Dag,
    *,
    min_gain: float,
    prune_nats: float,
    min_reverse: float,
    max_parents: int | None,
    required: set[tuple[str, str]],
    max_moves: int = 10_000,
    on_move: Callable[[tuple[str, str, str, float]], None] | None = None,
    screen: tuple[LocalScores, int] | None = None,
) -> list[tuple[str, str, str, float]]:
    """Run phases 1 and 2 in place on ``dag``; returns the moves ``(move, parent, child, gain)``.

    ``on_move`` is called with each move as it is taken (a progress display); ``screen`` is
    the cheap scores and the number k of candidates they pass on (module docstring).
    """
    history: list[tuple[str, str, str, float]] = []

    def additions(child: str) -> list[tuple[float, str, str, str]]:
        ps = dag.parents[child]
        if max_parents is not None and len(ps) >= max_parents:
            return []
        cands = [p for p in allowed[child] if p not in ps and not dag.creates_cycle(p, child)]
        if not cands:
            return []
        if screen is not None and len(cands) > screen[1]:
            cands = _screened(screen, dag, child, ps, cands)
        base = scores.one(child, ps)
        vals = scores.many(child, [dag.sorted({*ps, p}) for p in cands])
        return [(v - base, "add", p, child) for p, v in zip(cands, vals, strict=True)]

    add_gain = {c: additions(c) for c in dag.names}
    for _ in range(max_moves):  # phase 1: greedy additions
        best = max((m for ms in add_gain.values() for m in ms), default=None)
        if best is None or best[0] < min_gain:
            break
        gain, _, p, c = best
        if dag.creates_cycle(p, c):  # a later addition closed this one off
            add_gain[c] = additions(c)
            continue
        dag.add(p, c)
        history.append(("add", p, c, float(gain)))
        if on_move is not None:
            on_move(history[-1])
        add_gain[c] = additions(c)

    for _ in range(max_moves):  # phase 2: add / remove / reverse, best first
        moves = [m for c in dag.names for m in additions(c) if m[0] >= min_gain]
        for p, c in dag.edges():
            if (p, c) in required:
                continue
            pa_c = dag.parents[c]
            drop = scores.one(c, tuple(q for q in pa_c if q != p)) - scores.one(c, pa_c)
            if drop > -prune_nats:
                moves.append((drop + prune_nats, "remove", p, c))
            if c in allowed[p] and (max_parents is None or len(dag.parents[p]) < max_parents):
                if not dag.other_path(p, c):
                    gain = (
                        drop + scores.one(p, dag.sorted({*dag.parents[p], c})) - scores.one(p, dag.parents[p])
                    )
                    if gain > min_reverse:
                        moves.append((gain, "reverse", p, c))
        if not moves:
            break
        gain, kind, p, c = max(moves)
        if kind == "add":
            dag.add(p, c)
        elif kind == "remove":
            dag.remove(p, c)
            gain -= prune_nats
        else:
            dag.remove(p, c)
            dag.add(c, p)
        history.append((kind, p, c, float(gain)))
        if on_move is not None:
            on_move(history[-1])
    return history
