"""One world's part of the LoT experiment: queries answered by the world model and by the simulator.

Every query's do-terms are compiled once, with the model (:func:`pal.language.evaluate.compile_plans`:
action inference for ``reach``/``push``, fixed for ``hold``); the same plans are then played in
the model world (S sampled residuals per situation, twin noise for counterfactuals) and in the
simulator (deterministic, S = 1), and the same evaluator grades them
(:func:`pal.language.evaluate.answer`). A query meets its target when

    |p_model - p_sim| <= tolerance,  or  p_sim in I_model and p_model in I_sim,

with I the 95 % interval p ± 1.96 se of each answer. A :class:`Section` is what a part adds
to the report: its metrics, tables, targets and figures.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import torch

from pal.lab.report import Table, Target
from pal.language.actions import CompileContext
from pal.language.evaluate import Answer, answer, compile_plans
from pal.language.signature import Signature
from pal.language.syntax import parse_query
from pal.language.world import ModelWorld, Situations, World

__all__ = ["QueryResult", "Section", "agree", "play_queries", "query_section"]


def agree(model: Answer, sim: Answer, tolerance: float) -> bool:
    """|p_m - p_s| <= tolerance, or each answer inside the other's 95 % interval."""
    if abs(model.p - sim.p) <= tolerance:
        return True
    (ml, mh), (sl, sh) = model.interval, sim.interval
    return ml <= sim.p <= mh and sl <= model.p <= sh


@dataclass(frozen=True)
class QueryResult:
    """One query's two answers."""

    text: str
    model: Answer
    sim: Answer

    def met(self, tolerance: float) -> bool:
        """The query's target (module docstring)."""
        return agree(self.model, self.sim, tolerance)


@dataclass(frozen=True)
class Section:
    """A part of the LoT report.

    Attributes:
        name: short key (``"pushing"``, ``"pusher"``, ...): metrics live under it.
        title: what the part shows, for the figure.
        metrics: JSON-ready numbers.
        tables: its tables. targets: its targets. notes: its notes.
        results: the query results (for the figure; empty for a part without queries).
    """

    name: str
    title: str
    metrics: Mapping[str, Any]
    tables: tuple[Table, ...]
    targets: tuple[Target, ...]
    notes: tuple[str, ...] = ()
    results: tuple[QueryResult, ...] = field(default_factory=tuple)


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
    """Compile each query once and answer it in both worlds (module docstring).

    Query k compiles with seed ``1000 seed + k`` and draws the model's noise with ``1000 seed + k + 500``.
    """
    out = []
    for k, text in enumerate(texts):
        query = parse_query(text, signature)
        context = CompileContext(
            model, situations, torch.Generator().manual_seed(seed * 1000 + k), horizon=horizon
        )
        plans = compile_plans(query, signature, context)
        noise = torch.Generator().manual_seed(seed * 1000 + k + 500)
        p_model = answer(
            query,
            signature,
            model_world,
            situations,
            plans,
            samples=samples,
            generator=noise,
            evaluations=context.evaluations,
        )
        p_sim = answer(query, signature, sim_world, situations, plans, samples=1)
        out.append(QueryResult(text, p_model, p_sim))
    return out


def _finite(x: float) -> float | None:
    return x if math.isfinite(x) else None


def _interval(a: Answer) -> str:
    lo, hi = a.interval
    return f"[{lo:.3f}, {hi:.3f}]" if math.isfinite(a.se) else "n/a"


def query_section(
    name: str,
    title: str,
    results: Sequence[QueryResult],
    tolerance: float,
    caption: str,
    metrics: Mapping[str, Any] | None = None,
    notes: Sequence[str] = (),
) -> Section:
    """The table, metrics and ``queries_met.<name>`` target of one world's query results."""
    met = [r.met(tolerance) for r in results]
    rows = [
        (
            r.text,
            r.model.p,
            _finite(r.model.se),
            _interval(r.model),
            r.sim.p,
            _finite(r.sim.se),
            _interval(r.sim),
            abs(r.model.p - r.sim.p),
            "met" if ok else "NOT met",
        )
        for r, ok in zip(results, met, strict=True)
    ]
    table = Table(
        f"{title}: world model against the simulator (same situations, same compiled plans)",
        (
            "query",
            "P model",
            "se model",
            "model 95 %",
            "P simulator",
            "se simulator",
            "simulator 95 %",
            "|diff|",
            "target",
        ),
        rows,
        caption=caption,
    )
    diffs = [abs(r.model.p - r.sim.p) for r in results]
    block: dict[str, Any] = {
        **dict(metrics or {}),
        "queries": [
            {"text": r.text, "model": r.model.to_dict(), "simulator": r.sim.to_dict(), "met": ok}
            for r, ok in zip(results, met, strict=True)
        ],
        "met": int(sum(met)),
        "n_queries": len(results),
        "max_abs_diff": float(max(diffs)),
    }
    target = Target(
        f"queries_met.{name}",
        float(sum(met)) / len(met),
        1.0,
        ">=",
        f"{title}: share of queries with |P_model - P_sim| <= {tolerance} or each inside the other's 95 % interval",
    )
    return Section(name, title, block, (table,), (target,), tuple(notes), tuple(results))
