"""Hierarchical against flat action inference on the same object goals (thesis §6.4.1, Eq. 6.3).

After the shared protocol (:mod:`pal.experiments.closed_loop.setup`: babbling, then the agent's
world model fitted on the true object positions, as in ``lot``), ``goals`` episodes as in C2 put
the box at a seeded start (``start_radius`` m from the shoulder, within ``bearing_deg`` of the
workspace's central bearing, random yaw), the ball out of reach, the arm at rest, and draw a goal
``distance`` m away in a direction ``cone_deg`` from the arm's sweep direction. Two planners get
the same start, the same goal and at most ``episode_steps`` steps; an episode succeeds when the
true box centre comes within ``tolerance`` m of the goal (it ends there):

- ``hierarchy`` (:mod:`pal.experiments.closed_loop.hierarchy_pushing`): per step the nested query
  X_object^tar -> Z_event^tar -> a*(t): the push event that brings the box to the goal (action
  inference on the object layer's active submodel), realised as hand waypoints behind the box
  along the push direction, then through it (:func:`~pal.experiments.closed_loop.hierarchy_pushing.push_phase`
  picks the current one), and the joint targets that bring the hand to the waypoint (action
  inference on the body layer's active submodel);
- ``flat``: the agent's goal-mode planner (:func:`pal.agent.plan.plan`: the sampling planner over
  ``setup.agent.plan.action.horizon`` steps through the whole world model towards the box target,
  warm-started, holding still when it predicts no progress, as :meth:`pal.agent.Agent.decide`).

Both read the same state from the simulator (joint angles, the sensed hand, the true object
positions), so the comparison is of the planners, not of perception. The cost of a decision is
the number of mechanism evaluations inside it (:func:`inference.hierarchy_count.count_evaluations`
over every model the planner uses); the hierarchy's first decision also pays its one-time
contextualisation (the layers' samples), later ones reuse it.
"""

from __future__ import annotations

import logging
import time
from collections import Counter
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import torch

from inference import SamplingConfig
from inference.hierarchy import Hierarchy, LevelQuery
from inference.hierarchy_count import count_evaluations
from models import WorldModel
from pal.agent.plan import plan
from pal.checks import check_float, check_int
from pal.experiments.closed_loop.c2 import BALL_PARK
from pal.experiments.closed_loop.hierarchy_pushing import (
    PHASES,
    HierarchyConfig,
    push_phase,
    pushing_hierarchy,
)
from pal.experiments.closed_loop.push_goals import GoalGeometry, push_goals
from pal.experiments.closed_loop.setup import (
    QUICK_SETUP,
    TINY_SETUP,
    SetupConfig,
    babbled_agent,
    fitted_model,
)
from pal.experiments.language.lot_play import Section
from pal.lab.registry import register
from pal.lab.report import Precondition, Report, Table, Target
from pal.sim.pushing import PushingEnv

__all__ = ["METHODS", "QUICK", "TINY", "Config", "compare", "goals", "hierarchy_section", "run"]

log = logging.getLogger(__name__)

METHODS = ("hierarchy", "flat")


@dataclass(frozen=True)
class Config:
    """The comparison's protocol (module docstring); lengths in metres, angles in degrees.

    Attributes:
        seed: master seed (babbling, fits, goals, the planners' seeds).
        setup: babbling and the agent's model; ``setup.agent.plan`` is the flat planner.
        hierarchy: the layers and the two levels' action inference.
        goals: episodes (one goal each), the same for both planners.
        episode_steps: step budget per episode.
        tolerance: success radius about the goal, m.
        geometry: the box's start and the goal, as in C2.
    """

    seed: int = 0
    setup: SetupConfig = SetupConfig()
    hierarchy: HierarchyConfig = HierarchyConfig()
    goals: int = 20
    episode_steps: int = 20
    tolerance: float = 0.02
    geometry: GoalGeometry = GoalGeometry()

    def __post_init__(self) -> None:
        check_int("seed", self.seed, minimum=0)
        check_int("goals", self.goals)
        check_int("episode_steps", self.episode_steps)
        check_float("tolerance", self.tolerance, 0.0, open_low=True)


QUICK = Config(setup=QUICK_SETUP, goals=10, episode_steps=12)
TINY = Config(
    setup=TINY_SETUP,
    hierarchy=HierarchyConfig(
        object_query=replace(HierarchyConfig().object_query, num_steps=10),
        body_query=LevelQuery(
            3,
            replace(
                HierarchyConfig().body_query.options,
                sampling=SamplingConfig(population=8, elites=2, iterations=2, refine_steps=3),
            ),
        ),
        context_samples=16,
    ),
    goals=1,
    episode_steps=2,
)


def goals(config: Config, heading: float, shoulder: np.ndarray) -> list[dict[str, Any]]:
    """The seeded episodes (:func:`pal.experiments.closed_loop.push_goals.push_goals`, stream 64)."""
    return push_goals(config.geometry, config.seed, config.goals, heading, shoulder, stream=64)


def _state(obs: np.ndarray, info: dict[str, Any], objects: tuple[str, ...]) -> dict[str, np.ndarray]:
    """The lag-1 roots now, from the simulator: joint angles, sensed hand, true object positions."""
    out = {"q_prev": np.asarray(obs[:2], np.float64), "ee_prev": np.asarray(info["hand"], np.float64)}
    for o in objects:
        out[f"pos_prev.{o}"] = np.asarray(info["truth"][o][:2], np.float64)
    return out


class _Flat:
    """The agent's goal-mode decision (module docstring), with its warm start."""

    def __init__(self, model: WorldModel, config: Config, seed: int) -> None:
        self.model, self.plan = model, config.setup.agent.plan
        self.rng = np.random.default_rng(np.random.SeedSequence([config.seed, 66, seed]))
        self.sequence: np.ndarray | None = None

    def models(self) -> tuple[WorldModel, ...]:
        return (self.model,)

    def decide(self, state: dict[str, np.ndarray], goal: np.ndarray) -> tuple[np.ndarray, str]:
        cfg, q = self.plan, state["q_prev"]
        if cfg.warm_start and self.sequence is not None:
            init = np.concatenate([self.sequence[1:], self.sequence[-1:]])
        else:
            init = np.tile(q, (cfg.action.horizon, 1))
        p = plan(self.model, state, {"box": goal}, cfg, seed=int(self.rng.integers(2**31)), init=init)
        self.sequence = p.sequence
        now = float(np.linalg.norm(state["pos_prev.box"] - goal))
        if p.objective > now - cfg.min_progress:
            self.sequence = None
            return q.copy(), "hold"
        return p.action, "goal"


class _Nested:
    """The hierarchy's decision: object target -> push event -> current waypoint -> joint targets."""

    def __init__(self, hierarchy: Hierarchy, config: HierarchyConfig) -> None:
        self.h, self.config = hierarchy, config

    def models(self) -> tuple[WorldModel, ...]:
        return tuple(self.h.layers[k].model for k in ("body", "object"))

    def decide(self, state: dict[str, np.ndarray], goal: np.ndarray) -> tuple[np.ndarray, str]:
        dtype = self.h.layers["body"].model.dtype
        st = {k: torch.as_tensor(v, dtype=dtype)[None] for k, v in state.items()}
        events, _, _ = self.h.event_targets({"pos.box": torch.as_tensor(goal, dtype=dtype)[None]}, st)
        phases = self.h.realise(events, st)
        k = push_phase(events, st, self.config)
        result, _ = self.h.actions(phases[k], st)
        return result.actions["act"][0].detach().numpy().astype(np.float64), PHASES[k]


def _episode(env: PushingEnv, planner: Any, spec: dict[str, Any], config: Config) -> dict[str, Any]:
    """One closed-loop episode; its record (success, steps, evaluations per decision, modes, box path)."""
    goal = np.asarray(spec["goal"], np.float64)
    obs, info = env.reset(seed=spec["seed"], options={"objects": {"box": spec["box"], "ball": BALL_PARK}})
    path, evaluations, modes, seconds = [], [], Counter(), 0.0
    for _ in range(config.episode_steps):
        state = _state(obs, info, env.objects)
        path.append(state["pos_prev.box"])
        if np.linalg.norm(state["pos_prev.box"] - goal) <= config.tolerance:
            break
        start = time.perf_counter()
        with count_evaluations(*planner.models()) as count:
            action, mode = planner.decide(state, goal)
        seconds += time.perf_counter() - start
        evaluations.append(count.total)
        modes[mode] += 1
        obs, _, _, _, info = env.step(np.clip(action, env.ctrl_low, env.ctrl_high))
    box = np.asarray(info["truth"]["box"][:2], np.float64)
    if len(path) == len(evaluations):
        path.append(box)
    error = float(np.linalg.norm(box - goal))
    return {
        "success": bool(error <= config.tolerance),
        "final_err_cm": 100 * error,
        "steps": len(evaluations),
        "evaluations": evaluations,
        "seconds": seconds,
        "modes": dict(modes),
        "path": np.array(path).tolist(),
    }


def compare(config: Config, progress_bar: bool = False) -> dict[str, Any]:
    """Both planners on the same goals (module docstring): per method the episodes and summaries."""
    agent = babbled_agent(config.setup, config.seed, progress_bar=progress_bar)
    model, rows = fitted_model(agent, config.setup, config.seed, "truth", np.arange(len(agent.history)))
    heading = agent.env.unwrapped.workspace_bearing
    shoulder = np.asarray(agent.env.unwrapped.layout.shoulder[:2])
    agent.env.close()
    hierarchy, layers = pushing_hierarchy(model, agent.history, config.hierarchy, seed=config.seed)
    specs = goals(config, heading, shoulder)
    env = PushingEnv(camera=False)
    episodes: dict[str, list[dict[str, Any]]] = {m: [] for m in METHODS}
    try:
        for k, spec in enumerate(specs):
            nested = _Nested(hierarchy, config.hierarchy)
            for method, planner in (("hierarchy", nested), ("flat", _Flat(model, config, k))):
                episodes[method].append(_episode(env, planner, spec, config))
            log.info(
                "goal %d: %s",
                k,
                ", ".join(f"{m} {episodes[m][-1]['final_err_cm']:.2f} cm" for m in METHODS),
            )
    finally:
        env.close()
    summary = {m: _summary(episodes[m]) for m in METHODS}
    return {
        "methods": summary,
        "episodes": episodes,
        "goals": [{"box": list(s["box"]), "goal": s["goal"].tolist()} for s in specs],
        "layers": layers,
        "fitted_rows": {k: int(v) for k, v in rows.items()},
    }


def _summary(episodes: list[dict[str, Any]]) -> dict[str, Any]:
    ev = np.array([e for ep in episodes for e in ep["evaluations"]], dtype=np.float64)
    decisions = max(len(ev), 1)
    modes: Counter[str] = sum((Counter(ep["modes"]) for ep in episodes), Counter())
    return {
        "success": float(np.mean([ep["success"] for ep in episodes])),
        "final_err_cm_median": float(np.median([ep["final_err_cm"] for ep in episodes])),
        "evaluations_median": float(np.median(ev)) if len(ev) else None,
        "evaluations_mean": float(ev.mean()) if len(ev) else None,
        "decisions": len(ev),
        "steps_mean": float(np.mean([ep["steps"] for ep in episodes])),
        "seconds_per_decision": float(sum(ep["seconds"] for ep in episodes) / decisions),
        "modes": dict(modes),
    }


def _ratio(a: float | None, b: float | None) -> float | None:
    return None if a is None or not b else a / b


def hierarchy_section(config: Config, progress_bar: bool = False) -> Section:
    """The comparison as a part of a report (:class:`pal.experiments.language.lot_play.Section`)."""
    out = compare(config, progress_bar)
    s = out["methods"]
    gap = s["hierarchy"]["success"] - s["flat"]["success"]
    ratio = _ratio(s["hierarchy"]["evaluations_mean"], s["flat"]["evaluations_mean"])
    metrics = {
        **{m: s[m] for m in METHODS},
        "success_gap": gap,
        "evaluations_ratio": ratio,
        "episodes": out["episodes"],
        "goals": out["goals"],
        "layers": out["layers"],
        "fitted_rows": out["fitted_rows"],
    }
    table = Table(
        "Hierarchical against flat action inference: the same object goals",
        (
            "method",
            "success",
            "evaluations / decision (median)",
            "(mean)",
            "steps (mean)",
            "final error [cm] (median)",
        ),
        [
            (
                m,
                s[m]["success"],
                s[m]["evaluations_median"],
                s[m]["evaluations_mean"],
                s[m]["steps_mean"],
                s[m]["final_err_cm_median"],
            )
            for m in METHODS
        ],
        caption=f"{config.goals} goal(s), at most {config.episode_steps} steps each; success: the true box "
        f"centre within {100 * config.tolerance:g} cm of the goal; evaluations: mechanism evaluations "
        "counted inside each decision.",
    )
    targets = (
        Target(
            "success_hier_minus_flat",
            gap,
            0.0,
            ">=",
            "share of goals reached by the hierarchy minus that of flat action inference (>= 0: equal or better)",
        ),
        Target(
            "evaluations_per_decision_hier_over_flat",
            ratio,
            1.0,
            "<",
            "mean mechanism evaluations per decision, hierarchy / flat (< 1: fewer)",
            Precondition.nonzero(
                s["flat"]["evaluations_mean"], "flat action inference's evaluations per decision"
            ),
        ),
    )
    notes = (
        f"Hierarchy against flat: seed {config.seed}, {config.setup.babble_steps} babbling steps, model fitted "
        "on true object positions; both planners read the simulator's state.",
        "Push gains of the object layer (dpos = A push): "
        + "; ".join(f"{o}: {v['push_rows']} push events" for o, v in out["layers"].items())
        + " (ridge prior: the identity).",
    )
    return Section(
        "hierarchy", "Hierarchical against flat action inference", metrics, (table,), targets, notes
    )


@register("hierarchy", config=Config, quick=QUICK, tiny=TINY)
def run(config: Config, progress_bar: bool = False) -> Report:
    """Hierarchical (object -> event -> body) against flat action inference on the same pushing goals."""
    section = hierarchy_section(config, progress_bar)
    return Report(
        "Hierarchy: nested against flat action inference on object goals (thesis Eq. 6.3)",
        dict(section.metrics),
        section.tables,
        section.targets,
        section.notes,
        figures={"comparison": _figure(section.metrics, config)},
    )


def _figure(m: dict[str, Any], config: Config) -> Any:
    """Success per method, evaluations per decision (log scale) and the box's distance to the goal."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11, 3.6))
    a, b, c = fig.subplots(1, 3)
    colours = {"hierarchy": "C0", "flat": "C3"}
    a.bar(list(METHODS), [m[k]["success"] for k in METHODS], color=[colours[k] for k in METHODS])
    a.set(ylim=(0, 1.05), ylabel="share of goals reached", title="success")
    for i, k in enumerate(METHODS):
        ev = [e for ep in m["episodes"][k] for e in ep["evaluations"]] or [1]
        b.scatter(
            np.full(len(ev), i) + np.linspace(-0.15, 0.15, len(ev)), ev, s=8, color=colours[k], alpha=0.6
        )
    b.set(xticks=range(len(METHODS)), xticklabels=METHODS, yscale="log", title="evaluations per decision")
    for k in METHODS:
        for j, (ep, g) in enumerate(zip(m["episodes"][k], m["goals"], strict=True)):
            d = 100 * np.linalg.norm(np.asarray(ep["path"]) - np.asarray(g["goal"]), axis=1)
            c.plot(np.arange(len(d)), d, color=colours[k], alpha=0.5, lw=1, label=k if j == 0 else None)
    c.axhline(100 * config.tolerance, color="k", ls=":", lw=1)
    c.set(xlabel="step", ylabel="box to goal, cm", title="episodes")
    c.legend(fontsize=7)
    fig.tight_layout()
    return fig
