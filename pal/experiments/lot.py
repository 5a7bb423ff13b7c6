"""LoT: grounded causal queries (thesis Eq. 6.10) answered by the world model and by the simulator.

The agent babbles in the pushing world and fits its world model on the true object positions
(so model and simulator share coordinates). N settled start situations are drawn
(:func:`pal.language.sim_worlds.pushing_situations`: a random arm, the box near the hand in
half of them). Every query's do-terms are compiled once, with the model (action inference for
``reach``/``push``, fixed for ``hold``); the same plans are then played in the model world
(S sampled residuals per situation) and in the simulator (deterministic, S = 1), and the same
evaluator grades them (:func:`pal.language.evaluate.answer`). A query meets its target when
|P_model - P_sim| <= 0.05 or each answer lies inside the other's 95 % interval.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from pal.checks import check_int
from pal.experiments.pushing_setup import QUICK_SETUP, TINY_SETUP, SetupConfig, babbled_agent, fitted_model
from pal.experiments.registry import register
from pal.experiments.report import Report, Table, Target
from pal.language.actions import CompileContext
from pal.language.evaluate import Answer, answer, compile_plans
from pal.language.sim_worlds import PushingWorld, pushing_situations
from pal.language.syntax import parse_query
from pal.language.vocabularies import pushing_signature
from pal.language.world import ModelWorld, Situations
from pal.sim.pushing import PushingEnv

__all__ = ["QUERIES", "Config", "agree", "run"]

#: The pushing-world queries (text syntax of :mod:`pal.language.syntax`).
QUERIES: tuple[str, ...] = (
    "P(touch(hand, box) | do(reach(hand, box)), near(hand, box))",
    "P(touch(hand, box) | do(reach(hand, box)))",
    "P(moving(box) | do(reach(hand, box)), near(hand, box))",
    "P(moving(box) | do(push(hand, box)), near(hand, box))",
    "P(near(hand, box) | do(hold(hand)), near(hand, box))",
    "P(touch(hand, box) | do(hold(hand)))",
    "P(moving(ball) | do(reach(hand, box)))",
    "P(near(hand, box) | do(reach(hand, box)), not near(hand, box))",
    "P(left_of(hand, box) | do(hold(hand)), left_of(hand, box))",
    "P(moving(box)[do(hold(hand))] | do(reach(hand, box)), moving(box)@end)",
)


@dataclass(frozen=True)
class Config:
    """Settings of the LoT experiment.

    Attributes:
        seed: seeds babbling, the fit, the situations and the residual samples.
        setup: babbling and the agent's model.
        situations: N start situations.
        samples: S residual samples per situation in the model world.
        horizon: steps of the compiled plans.
        queries: the query texts.
        tolerance: largest accepted |P_model - P_sim| (else the intervals must overlap both ways).
    """

    seed: int = 0
    setup: SetupConfig = SetupConfig()
    situations: int = 60
    samples: int = 32
    horizon: int = 1
    queries: tuple[str, ...] = QUERIES
    tolerance: float = 0.05

    def __post_init__(self) -> None:
        check_int("situations", self.situations, 2)
        check_int("samples", self.samples, 1)
        check_int("horizon", self.horizon, 1)
        if not self.queries:
            raise ValueError("queries must hold at least one query text")


QUICK = Config(setup=QUICK_SETUP, situations=40, samples=16)
TINY = Config(setup=TINY_SETUP, situations=4, samples=2, queries=QUERIES[:2] + QUERIES[-1:])


def agree(model: Answer, sim: Answer, tolerance: float) -> bool:
    """|p_m - p_s| <= tolerance, or each answer inside the other's 95 % interval."""
    if abs(model.p - sim.p) <= tolerance:
        return True
    (ml, mh), (sl, sh) = model.interval, sim.interval
    return ml <= sim.p <= mh and sl <= model.p <= sh


def _finite(x: float) -> float | None:
    return x if math.isfinite(x) else None


@register("lot", config=Config, quick=QUICK, tiny=TINY)
def run(config: Config, progress_bar: bool = False) -> Report:
    """LoT: each query answered by the world model and checked against the simulator."""
    agent = babbled_agent(config.setup, config.seed, progress_bar=progress_bar)
    model, rows = fitted_model(agent, config.setup, config.seed, "truth", np.arange(len(agent.history)))
    agent.env.close()
    sig = pushing_signature(horizon=config.horizon)
    env = PushingEnv(camera=False)
    try:
        values, states = pushing_situations(env, config.situations, np.random.default_rng([config.seed, 14]))
        sit = Situations({k: torch.as_tensor(v, dtype=model.dtype) for k, v in values.items()}, states)
        sim_world, model_world = PushingWorld(env), ModelWorld(model)
        results = []
        for k, text in enumerate(config.queries):
            query = parse_query(text, sig)
            gen = torch.Generator().manual_seed(config.seed * 1000 + k)
            context = CompileContext(model, sit, gen, horizon=config.horizon)
            plans = compile_plans(query, sig, context)
            noise = torch.Generator().manual_seed(config.seed * 1000 + k + 500)
            p_model = answer(
                query,
                sig,
                model_world,
                sit,
                plans,
                samples=config.samples,
                generator=noise,
                evaluations=context.evaluations,
            )
            p_sim = answer(query, sig, sim_world, sit, plans, samples=1)
            results.append((text, p_model, p_sim))
    finally:
        env.close()
    table_rows, met = [], []
    for text, m, s in results:
        ok = agree(m, s, config.tolerance)
        met.append(ok)
        table_rows.append(
            (text, m.p, _finite(m.se), s.p, _finite(s.se), abs(m.p - s.p), "met" if ok else "NOT met")
        )
    table = Table(
        "Queries: world model against the simulator (same situations, same compiled plans)",
        ("query", "P model", "se model", "P simulator", "se simulator", "|diff|", "target"),
        table_rows,
        caption=f"{config.situations} situations; model {config.samples} residual samples each; "
        f"target |diff| <= {config.tolerance} or each inside the other's 95 % interval.",
    )
    diffs = [abs(m.p - s.p) for _, m, s in results]
    metrics: dict[str, Any] = {
        "rows": {k: int(v) for k, v in rows.items()},
        "queries": [{"text": t, "model": m.to_dict(), "simulator": s.to_dict()} for t, m, s in results],
        "met": int(sum(met)),
        "max_abs_diff": float(max(diffs)),
    }
    targets = [
        Target(
            "queries_met",
            float(sum(met)) / len(met),
            1.0,
            ">=",
            "share of queries with |P_model - P_sim| <= 0.05 or inside both intervals",
        )
    ]
    return Report(
        "LoT: grounded causal queries, world model against simulator (thesis Eq. 6.10)",
        metrics,
        (table,),
        targets,
        notes=(
            f"Pushing world, seed {config.seed}, {config.setup.babble_steps} babbling steps, model fitted on "
            "true object positions; plans compiled once and played in both worlds.",
        ),
        figures={"model_vs_simulator": _figure(results)},
    )


def _figure(results: list) -> Any:
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    fig = Figure(figsize=(4.5, 4.5))
    ax = fig.subplots()
    for k, (_, m, s) in enumerate(results):
        ax.errorbar(
            s.p, m.p, xerr=1.96 * (s.se if math.isfinite(s.se) else 0.0), yerr=1.96 * m.se, fmt="o", capsize=2
        )
        ax.annotate(str(k + 1), (s.p, m.p), textcoords="offset points", xytext=(4, 4), fontsize=7)
    ax.plot([0, 1], [0, 1], "k--", lw=0.8)
    ax.set(xlim=(-0.05, 1.05), ylim=(-0.05, 1.05), xlabel="P simulator", ylabel="P world model")
    ax.set_title("queries (numbers: table rows)", fontsize=9)
    return fig
