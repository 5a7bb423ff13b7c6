"""LoT: grounded causal queries (thesis Eq. 6.10) answered by the world model and by the simulator.

Two worlds, each a :class:`pal.experiments.language.lot_play.Section` of the report:

- **Pushing world.** The agent babbles (:mod:`pal.experiments.closed_loop.setup`); two world
  models are fitted on the same babbling, on the true object positions (so model and simulator
  share coordinates): the primary, the gated displacement form (``contact.o`` a Bernoulli switch,
  observed from touch in training, ``dpos.o`` exactly at rest without contact), and, with
  ``comparison``, the smooth form beside it. The simulator reports ``contact.o`` as each model
  defines it (a 0/1 touch for the gated model, the touched share of the step for the smooth one),
  so ``touch`` grades the same quantity in both worlds. N start
  situations are drawn (:func:`pal.language.sim_worlds.pushing_situations`: a random arm, the
  box near the hand in half of them, then, with ``babbling_starts``, one babbling step, so the
  arm moves as in the steps the model learned from: it does not sense joint velocities).
- **Pusher-v5** (:mod:`pal.experiments.language.lot_pusher`), unless ``pusher`` is None.
- **Hierarchy against flat action inference** on object goals
  (:mod:`pal.experiments.closed_loop.hierarchy_compare`, also its own experiment ``hierarchy``), unless
  ``hierarchy`` is None.

Every query's do-terms are compiled once with each model; the same plans are played in that
model's world (S sampled residuals per situation) and in the simulator (deterministic, S = 1),
and graded by the same evaluator. A query meets its target when |P_model - P_sim| <= 0.05 or
each answer lies inside the other's 95 % interval; every query has its own target per model
(evaluated when its evidence holds in at least 20 situations), and the share of queries met is
a target over all and per world and model.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import torch

from pal.agent import AgentConfig, ModelConfig
from pal.agent.config import DISPLACEMENTS
from pal.agent.graph import contact_rule
from pal.checks import check_float, check_int
from pal.experiments.closed_loop import hierarchy_compare
from pal.experiments.closed_loop.setup import TINY_SETUP, SetupConfig, babbled_agent
from pal.experiments.language.lot_play import (
    QueryResult,
    Section,
    agree,
    fitted_models,
    play_queries,
    query_section,
)
from pal.experiments.language.lot_pusher import QUICK_PUSHER, TINY_PUSHER, PusherPart, pusher_section
from pal.lab.registry import register
from pal.lab.report import Report, Target
from pal.language.sim_worlds import PushingWorld, pushing_situations
from pal.language.vocabularies import pushing_signature
from pal.language.world import ModelWorld, Situations
from pal.perception.grounding import GroundingConfig
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
        seed: seeds babbling, the fits, the situations and the residual samples.
        setup: babbling and the primary world model (``setup.agent.model``) in the pushing world.
        comparison: the displacement form of the comparison model in both worlds (the primary's
            ModelConfig with this form, fitted on the same data), or None for the primary alone.
        situations: N start situations (pushing world).
        num_samples: S residual samples per situation in the model world (pushing world).
        horizon: steps of the compiled plans (pushing world).
        queries: the pushing-world query texts.
        babbling_starts: the situations are one babbling step after a settled draw (else settled).
        tolerance: largest accepted |P_model - P_sim| (else the intervals must overlap both ways).
        position_sigma: the position uncertainty the built-in predicates grade with, m (both
            worlds report true positions); None: the perception floor (1 cm).
        pusher: the Pusher-v5 part, or None to leave it out.
        hierarchy: the hierarchy-against-flat comparison (its seed is replaced by ``seed``), or None.
    """

    seed: int = 0
    setup: SetupConfig = SetupConfig(agent=AgentConfig(model=ModelConfig(displacement="gated")))
    comparison: str | None = "smooth"
    situations: int = 60
    num_samples: int = 32
    horizon: int = 1
    queries: tuple[str, ...] = QUERIES
    babbling_starts: bool = True
    tolerance: float = 0.05
    position_sigma: float | None = None
    pusher: PusherPart | None = PusherPart()
    hierarchy: hierarchy_compare.Config | None = hierarchy_compare.Config()

    def __post_init__(self) -> None:
        check_int("situations", self.situations, 2)
        check_int("num_samples", self.num_samples, 1)
        check_int("horizon", self.horizon, 1)
        check_float("tolerance", self.tolerance, 0.0)
        if self.position_sigma is not None:
            check_float("position_sigma", self.position_sigma, 0.0, open_low=True)
        if not self.queries:
            raise ValueError("queries must hold at least one query text")
        if self.comparison is not None:
            if self.comparison not in DISPLACEMENTS:
                raise ValueError(
                    f"comparison {self.comparison!r} unknown; expected one of {list(DISPLACEMENTS)} or None"
                )
            forms = {self.setup.agent.model.displacement}
            if self.pusher is not None:
                forms.add(self.pusher.model.displacement)
            if self.comparison in forms:
                raise ValueError(
                    f"comparison {self.comparison!r} is the primary model's displacement form; give the other one or None"
                )


#: ``--quick``: 1000 babbling steps (240, the other experiments' quick babbling, leave the
#: contact and displacement mechanisms too rough for these queries).
QUICK = Config(
    setup=SetupConfig(babble_steps=1000, agent=AgentConfig(model=ModelConfig(displacement="gated"))),
    situations=40,
    num_samples=16,
    pusher=QUICK_PUSHER,
    hierarchy=hierarchy_compare.QUICK,
)
TINY = Config(
    setup=replace(
        TINY_SETUP,
        agent=replace(TINY_SETUP.agent, model=replace(TINY_SETUP.agent.model, displacement="gated")),
    ),
    situations=4,
    num_samples=2,
    queries=QUERIES[:2] + QUERIES[-1:],
    pusher=TINY_PUSHER,
    hierarchy=hierarchy_compare.TINY,
)


def grounding(config: Config) -> GroundingConfig | None:
    """The built-ins' scales: the perception defaults, with ``position_sigma`` as the floor when set."""
    return None if config.position_sigma is None else GroundingConfig(position_floor=config.position_sigma)


def _pushing_section(config: Config, progress_bar: bool) -> Section:
    agent = babbled_agent(config.setup, config.seed, progress_bar=progress_bar)
    rows = np.arange(len(agent.history))
    models = fitted_models(agent, config.setup.agent.model, config.comparison, config.seed, "truth", rows)
    spec = agent.spec
    agent.env.close()
    b = config.setup.agent.babble
    env = PushingEnv(camera=False)
    try:
        values, states = pushing_situations(
            env,
            config.situations,
            np.random.default_rng([config.seed, 14]),
            babble=(b.local, b.reach) if config.babbling_starts else None,
        )
        results = {}
        for name, (model, _) in models.items():
            sit = Situations({k: torch.as_tensor(v, dtype=model.dtype) for k, v in values.items()}, states)
            rule, _ = contact_rule(spec, replace(config.setup.agent.model, displacement=name))
            results[name] = play_queries(
                config.queries,
                pushing_signature(horizon=config.horizon, grounding=grounding(config)),
                model,
                ModelWorld(model),
                PushingWorld(env, contact=rule),
                sit,
                samples=config.num_samples,
                horizon=config.horizon,
                seed=config.seed,
            )
    finally:
        env.close()
    start = "one babbling step after a settled draw" if config.babbling_starts else "settled"
    return query_section(
        "pushing",
        "Pushing world",
        results,
        config.tolerance,
        caption=f"{config.situations} situations ({start}); plans over {config.horizon} step(s); "
        f"model {config.num_samples} residual samples each; each model's plans played in the simulator.",
        metrics={"rows": {n: r for n, (_, r) in models.items()}, "babble_steps": config.setup.babble_steps},
        notes=(
            f"Pushing world, seed {config.seed}, {config.setup.babble_steps} babbling steps, models "
            f"({', '.join(models)}) fitted on the same true object positions; each model's plans "
            "compiled once and played in it and in the simulator.",
        ),
    )


def sections(config: Config, progress_bar: bool = False) -> list[Section]:
    """The report's parts: the pushing world, then Pusher-v5 and the hierarchy comparison (when configured).

    Each part brings its own metrics, tables, targets and notes.
    """
    out = [_pushing_section(config, progress_bar)]
    if config.pusher is not None:
        out.append(
            pusher_section(config.pusher, config.seed, config.tolerance, grounding(config), config.comparison)
        )
    if config.hierarchy is not None:
        h = replace(config.hierarchy, seed=config.seed)
        out.append(hierarchy_compare.hierarchy_section(h, progress_bar))
    return out


@register("lot", config=Config, quick=QUICK, tiny=TINY)
def run(config: Config, progress_bar: bool = False) -> Report:
    """LoT: each query answered by the world model and checked against the simulator, per world."""
    parts = sections(config, progress_bar)
    results = [r for s in parts for r in s.results]
    met = [r.met(config.tolerance) for r in results]
    diffs = [d for d in (r.diff for r in results) if d is not None]
    metrics: dict[str, Any] = {s.name: dict(s.metrics) for s in parts}
    metrics.update(
        met=int(sum(met)),
        n_queries=len(results),
        max_abs_diff=float(max(diffs)) if diffs else None,
    )
    own = [
        t
        for s in parts
        for t in s.targets
        if s.results and t.name.startswith(f"query.{s.name}.{s.metrics['model']}.")
    ]
    targets = [
        Target(
            "queries_met",
            float(sum(bool(t.met) for t in own)) / max(len(own), 1),
            1.0,
            ">=",
            f"share of all queries of the primary models whose own target is met (|P_model - P_sim| <= "
            f"{config.tolerance} or inside both intervals, the evidence holding in >= 20 situations)",
        )
    ]
    for s in parts:
        targets.extend(s.targets)
    return Report(
        "LoT: grounded causal queries, world model against simulator (thesis Eq. 6.10)",
        metrics,
        tuple(t for s in parts for t in s.tables),
        targets,
        notes=tuple(n for s in parts for n in s.notes),
        figures={"model_vs_simulator": _figure([s for s in parts if s.results])},
    )


def _figure(parts: list[Section]) -> Any:
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    fig = Figure(figsize=(4.5 * len(parts), 4.5))
    axes = fig.subplots(1, len(parts), squeeze=False)[0]
    for ax, part in zip(axes, parts, strict=True):
        primary = part.metrics.get("model", "model")
        _panel(ax, part.results, "o", primary)
        for (name, results), marker in zip(part.comparisons.items(), "sd^v", strict=False):
            _panel(ax, results, marker, name)
        ax.legend(fontsize=7, loc="upper left")
        ax.set_title(f"{part.title} (numbers: table rows)", fontsize=9)
    return fig


def _panel(ax: Any, results: tuple[QueryResult, ...], marker: str, label: str) -> None:
    first = True
    for k, r in enumerate(results):
        m, s = r.model, r.sim
        if m is None or s is None:
            continue
        ax.errorbar(
            s.p,
            m.p,
            xerr=1.96 * (s.se if math.isfinite(s.se) else 0.0),
            yerr=1.96 * (m.se if math.isfinite(m.se) else 0.0),
            fmt=marker,
            capsize=2,
            mfc="none" if marker != "o" else None,
            label=label if first else None,
        )
        first = False
        ax.annotate(str(k + 1), (s.p, m.p), textcoords="offset points", xytext=(4, 4), fontsize=7)
    ax.plot([0, 1], [0, 1], "k--", lw=0.8)
    ax.set(xlim=(-0.05, 1.05), ylim=(-0.05, 1.05), xlabel="P simulator", ylabel="P world model")
