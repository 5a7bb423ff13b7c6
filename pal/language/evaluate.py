"""Answering a query (thesis Eq. 6.10): a probability with its Monte-Carlo standard error.

For N situations, S samples each, evidence weights w_is = prod_j g_{e_j} (soft rejection) and
outcome grades g_is = prod_k g_{o_k}:

    p = sum_is w_is g_is / sum_is w_is

With situations as clusters (Y_i = sum_s w_is g_is, W_i = sum_s w_is, W-bar = mean W_i), the
delta-method (ratio-estimator) variance is

    var(p) = sum_i (Y_i - p W_i)^2 / (N (N - 1) W-bar^2)

(with one situation, its samples are the clusters). The effective sample size is
(sum w)^2 / sum w^2. The do-terms compile to one plan (N, T, A), their plans concatenated in
time; a counterfactual query plays the factual and the counterfactual plan in twin worlds that
share exogenous noise, weighs the pairs by the factual evidence and grades the outcome in the
counterfactual world. :func:`compile_plans` and :func:`answer` are apart so that the same
plans can be played in several worlds (the model and the simulator).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import torch
from torch import Tensor

from pal.language.actions import CompileContext
from pal.language.predicates import conjunction
from pal.language.signature import LanguageError, Signature
from pal.language.terms import Query
from pal.language.world import Outcome, Situations, World

__all__ = ["Answer", "EvidenceError", "P", "answer", "compile_plans", "evaluate"]

#: Total evidence weight per (situation, sample) below which the evidence is taken as impossible.
MIN_WEIGHT = 1e-9


class EvidenceError(LanguageError):
    """Evidence whose total weight is (almost) zero in every situation and sample."""


@dataclass(frozen=True)
class Answer:
    """A query's answer.

    Attributes:
        p: the probability, in [0, 1].
        se: its Monte-Carlo standard error (module docstring).
        n_situations: N.
        samples: S per situation.
        ess: effective sample size of the evidence weights.
        query: the query's text.
        evaluations: model evaluations per situation spent compiling the do-terms, by term.
    """

    p: float
    se: float
    n_situations: int
    samples: int
    ess: float
    query: str = ""
    evaluations: Mapping[str, float] = field(default_factory=dict)

    @property
    def interval(self) -> tuple[float, float]:
        """The 95 % interval p ± 1.96 se, clipped to [0, 1]."""
        return max(0.0, self.p - 1.96 * self.se), min(1.0, self.p + 1.96 * self.se)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready fields."""
        lo, hi = self.interval
        return {
            "query": self.query,
            "p": self.p,
            "se": self.se,
            "interval": [lo, hi],
            "n_situations": self.n_situations,
            "samples": self.samples,
            "ess": self.ess,
            "evaluations": dict(self.evaluations),
        }


def _plan(terms: tuple, signature: Signature, context: CompileContext, what: str) -> Tensor:
    parts = []
    for a in terms:
        t, constants = signature.action(a)
        if t.compile is None:
            raise LanguageError(f"{what}: action term {t.name!r} has no compile function bound")
        parts.append(t.compile(context, constants))
    return torch.cat(parts, 1)


def compile_plans(query: Query, signature: Signature, context: CompileContext) -> list[Tensor]:
    """The query's plans: ``[factual]`` or ``[factual, counterfactual]``, each (N, T, A).

    A query without do-terms plays no steps: its plan is (N, 0, A).
    """
    signature.check(query)
    n = context.situations.n
    a = sum(d for _, d in context.layout or ())
    empty = torch.zeros(n, 0, a, dtype=context.dtype)
    factual = _plan(query.interventions, signature, context, "do") if query.interventions else empty
    if query.counterfactual is None:
        return [factual]
    return [factual, _plan(query.counterfactual, signature, context, "counterfactual do")]


def _ratio(w: Tensor, g: Tensor) -> tuple[float, float]:
    """The estimate p and its clustered delta-method se from (N, S) weights and grades."""
    if w.shape[0] == 1:
        w, g = w.T, g.T  # one situation: its samples are the clusters
    y_i, w_i = (w * g).sum(1), w.sum(1)
    n = w_i.shape[0]
    p = float(y_i.sum() / w_i.sum())
    if n < 2:
        return p, float("nan")
    resid = y_i - p * w_i
    var = float((resid**2).sum()) / (n * (n - 1) * float(w_i.mean()) ** 2)
    return min(max(p, 0.0), 1.0), math.sqrt(max(var, 0.0))


def _static(situations: Situations) -> Outcome:
    """The situations as a zero-step outcome (S = 1)."""
    return Outcome({k: torch.as_tensor(v)[:, None, None, :] for k, v in situations.values.items()})


def _check_world(world: Any) -> None:
    if not callable(getattr(world, "play", None)):
        raise TypeError(
            f"world must be a World (a ModelWorld or a simulator world with play(situations, plans, "
            f"samples, generator)), got {type(world).__name__}"
        )


def answer(
    query: Query,
    signature: Signature,
    world: World,
    situations: Situations,
    plans: list[Tensor],
    *,
    samples: int = 64,
    generator: torch.Generator | None = None,
    evaluations: Mapping[str, float] | None = None,
) -> Answer:
    """Play the plans in ``world`` from the situations and estimate the query's probability.

    Args:
        query: the query (checked against the signature).
        signature: its constants, predicates and action terms.
        world: the world to play (:class:`~pal.language.world.ModelWorld`, a simulator world).
        situations: the N start situations.
        plans: :func:`compile_plans` of the query, (N, T, A) each.
        samples: S per situation (a deterministic world returns 1).
        generator: the exogenous noise (default seeded 0).
        evaluations: compilation cost to report.

    Raises:
        EvidenceError: the evidence has total weight ~0.
        LanguageError: plans that do not match the query (one, or two for a counterfactual).
    """
    signature.check(query)
    _check_world(world)
    want = 2 if query.is_counterfactual else 1
    if len(plans) != want:
        raise LanguageError(f"{query}: expected {want} plan(s), got {len(plans)}")
    if isinstance(samples, bool) or not isinstance(samples, int) or samples < 1:
        raise LanguageError(f"samples must be an int >= 1, got {samples!r}")
    gen = generator if generator is not None else torch.Generator().manual_seed(0)
    if not query.is_counterfactual and plans[0].shape[1] == 0:
        outcomes = [_static(situations)]
    else:
        outcomes = world.play(situations, plans, samples, gen)
    factual, result = outcomes[0], outcomes[-1]
    g = conjunction(query.outcome, signature, result)
    assert g is not None
    w = conjunction(query.evidence, signature, factual)
    w = torch.ones_like(g) if w is None else w.to(g.dtype)
    if float(w.sum()) < MIN_WEIGHT * w.numel():
        raise EvidenceError(
            f"{query}: the evidence {', '.join(map(str, query.evidence))} has total weight "
            f"{float(w.sum()):.3g} over {w.numel()} samples; it (almost) never holds in these situations"
        )
    p, se = _ratio(w.double(), g.double())
    ess = float(w.sum() ** 2 / (w**2).sum())
    return Answer(p, se, situations.n, int(g.shape[1]), ess, str(query), dict(evaluations or {}))


def evaluate(
    query: Query | str,
    signature: Signature,
    world: World,
    situations: Situations,
    *,
    model: Any = None,
    samples: int = 64,
    seed: int = 0,
    horizon: int = 1,
) -> Answer:
    """Compile the query's do-terms (with ``model`` for inferred terms) and answer it in ``world``."""
    _check_world(world)
    if isinstance(query, str):
        from pal.language.syntax import parse_query

        query = parse_query(query, signature)
    gen = torch.Generator().manual_seed(int(seed))
    layout = getattr(world, "layout", None)
    context = CompileContext(model, situations, gen, horizon=horizon, layout=layout)
    plans = compile_plans(query, signature, context)
    return answer(
        query,
        signature,
        world,
        situations,
        plans,
        samples=samples,
        generator=torch.Generator().manual_seed(int(seed) + 1),
        evaluations=context.evaluations,
    )


def P(
    query: Query | str, signature: Signature, world: World, situations: Situations, **options: Any
) -> Answer:
    """``P("touch(hand, box) | do(reach(hand, box)), near(hand, box)", sig, world, situations)``."""
    return evaluate(query, signature, world, situations, **options)
