"""Edge selection after the search: backward elimination with a calibrated threshold.

For a child i with parents pa_i, the held-out log-likelihood ratio of parent j is

    Delta_ji = S_i(pa_i) - S_i(pa_i - j) = sum_r d_r,    d_r = l_r(pa_i) - l_r(pa_i - j),

with l_r the per-row held-out log-likelihoods (:meth:`inference.crossfit.CrossFitScorer.row_scores`).
Because every row is predicted by a model that did not see it, an irrelevant parent has
E[Delta_ji] <= 0, and Delta_ji's spread across rows is measured by its standard error

    se_ji = sqrt(N) sd(d_r),       z_ji = Delta_ji / se_ji.

An edge earns its place when Delta_ji >= ``prune_nats`` *and* z_ji >= ``min_z``: a fixed
number of nats alone lets heavy-tailed or misspecified data keep edges whose gain comes from
a few rows (a large se), which the z test refuses. Per child, the parent with the smallest Delta
below ``prune_nats`` (else the one with the smallest z below ``min_z``) is removed and the rest re-tested, until every parent passes or is
required.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from inference.search import LocalScores

__all__ = ["prune"]


def _z(scores: LocalScores, child: str, parents: list[str], p: str, delta: float) -> float:
    """Z of parent ``p`` (inf when the per-row differences do not vary)."""
    d = scores.rows(child, tuple(parents)) - scores.rows(child, tuple(q for q in parents if q != p))
    se = float(d.std()) * math.sqrt(d.numel()) if d.numel() > 1 else 0.0
    if se <= 0:
        return math.inf if delta > 0 else -math.inf
    return delta / se


def prune(
    scores: LocalScores,
    dag_parents: dict[str, list[str]],
    index: Mapping[str, int],
    prune_nats: float,
    required: set[tuple[str, str]],
    min_z: float = 0.0,
) -> tuple[dict[tuple[str, str], float], dict[tuple[str, str], float], float]:
    """Backward elimination per child (module docstring), in place on ``dag_parents``.

    Returns edge -> Delta (nats), edge -> z and the total score of the kept graph (nats).
    """
    ratios: dict[tuple[str, str], float] = {}
    zs: dict[tuple[str, str], float] = {}
    total = 0.0
    for child, parents in dag_parents.items():
        while True:
            full = scores.one(child, tuple(parents))
            if not parents:
                total += full
                break
            reduced = scores.many(child, [tuple(q for q in parents if q != p) for p in parents])
            deltas = {p: full - r for p, r in zip(parents, reduced, strict=True)}
            free = [p for p in parents if (p, child) not in required]
            z = {p: _z(scores, child, parents, p, deltas[p]) if min_z > 0 else math.inf for p in free}
            small = [p for p in free if deltas[p] < prune_nats]
            noisy = [p for p in free if z[p] < min_z]
            if small or noisy:
                weakest = min(small, key=deltas.__getitem__) if small else min(noisy, key=z.__getitem__)
                parents = sorted((q for q in parents if q != weakest), key=index.__getitem__)
                continue
            total += full
            ratios.update({(p, child): d for p, d in deltas.items()})
            zs.update({(p, child): z.get(p, math.inf) for p in parents})
            break
        dag_parents[child] = parents
    return ratios, zs, total
