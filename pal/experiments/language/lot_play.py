"""One world's part of the LoT experiment: queries answered by world models and by the simulator.

Every query's do-terms are compiled with a model (:func:`pal.language.evaluate.compile_plans`:
action inference for ``reach``/``push``, fixed for ``hold``); the same plans are then played in
that model's world (S sampled residuals per situation, twin noise for counterfactuals) and in
the simulator (deterministic, S = 1), and the same evaluator grades them
(:func:`pal.language.evaluate.answer`). A part may compare several models fitted on the same
data (e.g. the gated and the smooth displacement form): each compiles its own plans and is
compared with the simulator playing them. A query meets its target when

    |p_model - p_sim| <= tolerance,  or  p_sim in I_model and p_model in I_sim,

with I the 95 % interval p ± 1.96 se of each answer; since p lies in [0, 1] this is
``|p_model - p_sim| <= max(tolerance, 1.96 min(se_model, se_sim))`` (a NaN se counts as 0).
Each query's target is evaluated only when its evidence holds in at least ``min_situations``
situations (the effective number of the simulator's evidence weights, (sum w)^2 / sum w^2);
a query whose evidence never holds in a world has no answer there (None, with the reason).
A :class:`Section` is what a part adds to the report: its metrics, tables, targets and figures.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import torch

from pal.agent import Agent, ModelConfig, build_graph, build_model, fit_model
from pal.lab.report import Precondition, Table, Target
from pal.language.actions import CompileContext
from pal.language.evaluate import Answer, EvidenceError, answer, compile_plans
from pal.language.signature import Signature
from pal.language.syntax import parse_query
from pal.language.world import ModelWorld, Situations, World

__all__ = [
    "MIN_SITUATIONS",
    "QueryResult",
    "Section",
    "agree",
    "allowance",
    "fitted_models",
    "play_queries",
    "query_section",
    "query_targets",
]

#: Fewest (effective) situations in which a query's evidence holds for its target to be evaluated.
MIN_SITUATIONS = 20


def _se(a: Answer) -> float:
    return a.se if math.isfinite(a.se) else 0.0


def allowance(model: Answer, sim: Answer, tolerance: float) -> float:
    """The largest accepted |p_model - p_sim|: ``max(tolerance, 1.96 min(se_model, se_sim))``."""
    return max(tolerance, 1.96 * min(_se(model), _se(sim)))


def agree(model: Answer, sim: Answer, tolerance: float) -> bool:
    """|p_m - p_s| <= tolerance, or each answer inside the other's 95 % interval."""
    if abs(model.p - sim.p) <= tolerance:
        return True
    (ml, mh), (sl, sh) = model.interval, sim.interval
    return ml <= sim.p <= mh and sl <= model.p <= sh


@dataclass(frozen=True)
class QueryResult:
    """One query's two answers; None where the query's evidence never holds (``reason`` says where)."""

    text: str
    model: Answer | None
    sim: Answer | None
    reason: str = ""

    @property
    def diff(self) -> float | None:
        """|p_model - p_sim|, or None without both answers."""
        return None if self.model is None or self.sim is None else abs(self.model.p - self.sim.p)

    def met(self, tolerance: float) -> bool:
        """The query's target (module docstring); False without both answers."""
        return self.model is not None and self.sim is not None and agree(self.model, self.sim, tolerance)


@dataclass(frozen=True)
class Section:
    """A part of the LoT report.

    Attributes:
        name: short key (``"pushing"``, ``"pusher"``, ...): metrics live under it.
        title: what the part shows, for the figure.
        metrics: JSON-ready numbers.
        tables: its tables. targets: its targets. notes: its notes.
        results: the primary model's query results (for the figure; empty for a part without queries).
        comparisons: the comparison models' query results, by model name.
    """

    name: str
    title: str
    metrics: Mapping[str, Any]
    tables: tuple[Table, ...]
    targets: tuple[Target, ...]
    notes: tuple[str, ...] = ()
    results: tuple[QueryResult, ...] = field(default_factory=tuple)
    comparisons: Mapping[str, tuple[QueryResult, ...]] = field(default_factory=dict)


def fitted_models(
    agent: Agent, primary: ModelConfig, comparison: str | None, seed: int, source: str, rows: Any = None
) -> dict[str, tuple[Any, dict[str, int]]]:
    """The primary model and, with ``comparison``, that displacement form of it, both fitted on the same rows.

    Each is built from the agent's spec (:func:`pal.agent.build_graph` with its own displacement
    form) and fitted with :func:`pal.agent.fit_model` on ``rows`` of the agent's history
    (positions from ``source``), seeded alike.

    Returns:
        displacement form (``"gated"``, ``"smooth"``) -> ``(model, fitted rows by part)``, the primary first.

    Raises:
        ValueError: ``comparison`` equal to the primary's form.
    """
    configs = [primary]
    if comparison is not None:
        if comparison == primary.displacement:
            raise ValueError(f"the comparison model's form {comparison!r} is the primary model's")
        configs.append(replace(primary, displacement=comparison))
    out = {}
    for m in configs:
        graph = build_graph(agent.spec, (agent.low, agent.high), displacement=m.displacement)
        model = build_model(agent.spec, graph, m, seed=seed)
        fitted = fit_model(model, agent.history, agent.spec, m, source=source, rows=rows, seed=seed)
        out[m.displacement] = (model, {k: int(v) for k, v in fitted["rows"].items()})
    return out


def _answer(world_name: str, *args: Any, **kwargs: Any) -> tuple[Answer | None, str]:
    try:
        return answer(*args, **kwargs), ""
    except EvidenceError as e:
        return None, f"{world_name}: {e}"


def play_queries(
    texts: Sequence[str],
    signature: Signature,
    model: Any,
    model_world: ModelWorld,
    sim_world: World,
    situations: Situations,
    *,
    samples: int,
    horizon: int,
    seed: int,
) -> list[QueryResult]:
    """Compile each query once with ``model`` and answer it in both worlds (module docstring).

    Query k compiles with seed ``1000 seed + k`` and draws the model's noise with ``1000 seed + k + 500``.
    Evidence that never holds in a world (:class:`pal.language.evaluate.EvidenceError`) leaves
    that world's answer None, with the error as the reason.
    """
    out = []
    for k, text in enumerate(texts):
        query = parse_query(text, signature)
        context = CompileContext(
            model, situations, torch.Generator().manual_seed(seed * 1000 + k), horizon=horizon
        )
        plans = compile_plans(query, signature, context)
        noise = torch.Generator().manual_seed(seed * 1000 + k + 500)
        p_model, why_model = _answer(
            "model",
            query,
            signature,
            model_world,
            situations,
            plans,
            samples=samples,
            generator=noise,
            evaluations=context.evaluations,
        )
        p_sim, why_sim = _answer("simulator", query, signature, sim_world, situations, plans, samples=1)
        out.append(QueryResult(text, p_model, p_sim, "; ".join(r for r in (why_model, why_sim) if r)))
    return out


def _cell(a: Answer | None) -> str:
    """``p [lo, hi]`` of an answer, ``n/a`` without one."""
    if a is None:
        return "n/a"
    if not math.isfinite(a.se):
        return f"{a.p:.3f} [n/a]"
    lo, hi = a.interval
    return f"{a.p:.3f} [{lo:.3f}, {hi:.3f}]"


def _precondition(r: QueryResult, min_situations: int) -> Precondition:
    want = f"the evidence holds in >= {min_situations} situations (effective number, simulator)"
    if r.sim is None or r.model is None:
        return Precondition(False, f"{want}; no answer: {r.reason}")
    return Precondition(bool(r.sim.ess >= min_situations), f"{want}; was {r.sim.ess:.1f}")


def query_targets(
    name: str, variant: str, results: Sequence[QueryResult], tolerance: float, min_situations: int
) -> list[Target]:
    """One target per query: ``query.<name>.<variant>.<k>`` (k from 1), |p_model - p_sim| <= its allowance.

    The value is None (verdict "not evaluated") when a world has no answer; the precondition
    (module docstring) says why.
    """
    out = []
    for k, r in enumerate(results, 1):
        limit = tolerance if r.model is None or r.sim is None else allowance(r.model, r.sim, tolerance)
        out.append(
            Target(
                f"query.{name}.{variant}.{k}",
                r.diff,
                limit,
                "<=",
                f"{r.text}: |P_model - P_sim| ({variant} model), at most {tolerance} or inside both 95 % intervals",
                _precondition(r, min_situations),
            )
        )
    return out


def _block(results: Sequence[QueryResult], tolerance: float) -> dict[str, Any]:
    met = [r.met(tolerance) for r in results]
    diffs = [d for d in (r.diff for r in results) if d is not None]
    return {
        "queries": [
            {
                "text": r.text,
                "model": None if r.model is None else r.model.to_dict(),
                "simulator": None if r.sim is None else r.sim.to_dict(),
                "met": ok,
                "reason": r.reason,
            }
            for r, ok in zip(results, met, strict=True)
        ],
        "met": int(sum(met)),
        "n_queries": len(results),
        "max_abs_diff": float(max(diffs)) if diffs else None,
    }


def _verdict(t: Target) -> str:
    if t.verdict == "not evaluated":
        return "not evaluated"
    return "met" if t.met else "NOT met"


def _table(
    title: str,
    results: Mapping[str, Sequence[QueryResult]],
    targets: Mapping[str, list[Target]],
    caption: str,
) -> Table:
    names = list(results)
    columns = ["query"]
    for v in names:
        columns += [f"P {v} [95 %]", f"P simulator, {v} plans [95 %]", f"|diff| {v}", f"target {v}"]
    rows = []
    for k, text in enumerate(r.text for r in results[names[0]]):
        row: list[Any] = [text]
        for v in names:
            r = results[v][k]
            row += [_cell(r.model), _cell(r.sim), r.diff, _verdict(targets[v][k])]
        rows.append(tuple(row))
    return Table(title, columns, rows, caption=caption)


def query_section(
    name: str,
    title: str,
    results: Mapping[str, Sequence[QueryResult]],
    tolerance: float,
    caption: str,
    metrics: Mapping[str, Any] | None = None,
    notes: Sequence[str] = (),
    min_situations: int = MIN_SITUATIONS,
) -> Section:
    """The table, metrics and targets of one world's query results, per model.

    Args:
        name: the part's key (metrics, target names).
        title: the part's title.
        results: model name -> its query results, the primary model first (all the same queries).
        tolerance: the agreement rule's tolerance.
        caption: the table's caption.
        metrics: the part's own metrics, put first.
        notes: the part's notes.
        min_situations: the per-query targets' precondition (module docstring).

    Targets: ``queries_met.<name>`` (the share of the primary model's queries whose own target
    is met; "not evaluated" counts as not met) and ``queries_met.<name>.<model>`` for every other
    model, then every query's own target (:func:`query_targets`). The metrics' ``met`` counts
    the agreement rule alone, whatever the number of situations.
    """
    if not results:
        raise ValueError("query_section needs the results of at least one model")
    variants = list(results)
    texts = [r.text for r in results[variants[0]]]
    for v in variants[1:]:
        if [r.text for r in results[v]] != texts:
            raise ValueError(f"the {v!r} model answered other queries than the {variants[0]!r} model")
    per_query = {v: query_targets(name, v, results[v], tolerance, min_situations) for v in variants}
    table = _table(
        f"{title}: world models against the simulator (same situations)", results, per_query, caption
    )
    block: dict[str, Any] = {
        **dict(metrics or {}),
        **_block(results[variants[0]], tolerance),
        "model": variants[0],
    }
    block["comparisons"] = {v: _block(results[v], tolerance) for v in variants[1:]}
    targets = []
    for v in variants:
        suffix = "" if v == variants[0] else f".{v}"
        targets.append(
            Target(
                f"queries_met.{name}{suffix}",
                float(sum(bool(t.met) for t in per_query[v])) / len(per_query[v]),
                1.0,
                ">=",
                f"{title}, {v} model: share of the queries whose own target is met (|P_model - P_sim| <= "
                f"{tolerance} or each inside the other's 95 % interval, the evidence holding in >= "
                f"{min_situations} situations)",
            )
        )
    for v in variants:
        targets += per_query[v]
    others = {v: tuple(results[v]) for v in variants[1:]}
    return Section(
        name, title, block, (table,), tuple(targets), tuple(notes), tuple(results[variants[0]]), others
    )
