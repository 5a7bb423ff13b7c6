"""Experiment ``pusher-ceiling``: what the planner reaches on Pusher-v5 with a perfect model.

The ``pusher`` learners plan with learned models; their result mixes the model's error with the
planner's. Here the planner predicts with the true simulator from the exact state
(:class:`pal.baselines.simulator_mpc.SimulatorMPC`), so only the planner's settings, its step
cost and the episode length remain. For every population P of ``populations`` (10 % elites, the
iterations of ``plan``), every weight w_g of ``goal_weights`` on the object-goal term of the step
cost and every shaping weight w_b of ``behind_weights`` (the term that pulls the fingertip behind
the object on the far side from the goal, :func:`pal.agent.plan.behind`), the planner runs
``goals`` seeded Pusher-v5 episodes of ``steps`` steps and is scored by

    d_final = |object - goal|_xy at the episode's end     (median, share <= ``success``),

with its planning CPU seconds per step on one torch thread. The ``pusher`` experiment's
targets (median <= 0.10 m, >= 40 % within 5 cm at 6k steps) are reachable by a learner with its
settings only if they are reachable here.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from typing import Any

import gymnasium
import numpy as np

from pal.agent import PlanConfig
from pal.checks import check_float, check_int
from pal.experiments.closed_loop.pusher import PLAN
from pal.experiments.closed_loop.pusher_runs import ENV_ID, MOVED, simulator_episode
from pal.lab.registry import register
from pal.lab.report import Precondition, Report, Table, Target
from pal.lab.timing import torch_threads

__all__ = ["Config", "run", "sized"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Config:
    """Settings of the ``pusher-ceiling`` experiment (module docstring).

    Attributes:
        seed: the first goal's seed (goal g resets with ``seed + g``, the planner too).
        goals: episodes per setting. steps: steps per episode (Pusher-v5 truncates at 100).
        plan: the planner and cost (the ``pusher`` experiment's); population, goal weight and
            behind weight are replaced by the grid's.
        populations: population sizes P. goal_weights: object-goal weights w_g (PETS: 1.25).
        behind_weights: shaping weights w_b (0: no shaping).
        success: an episode succeeds when it ends within this x-y distance, m.
        threads: torch threads (one core: 1).
    """

    seed: int = 0
    goals: int = 20
    steps: int = 100
    plan: PlanConfig = PLAN
    populations: tuple[int, ...] = (PLAN.action.sampling.population,)
    goal_weights: tuple[float, ...] = (1.25, PLAN.goal_weight)
    behind_weights: tuple[float, ...] = (0.0,)
    success: float = 0.05
    threads: int = 1

    def __post_init__(self) -> None:
        check_int("seed", self.seed, minimum=0)
        for name in ("goals", "threads"):
            check_int(name, getattr(self, name))
        check_int("steps", self.steps, maximum=100)
        for name in ("populations", "goal_weights", "behind_weights"):
            if not getattr(self, name):
                raise ValueError(f"{name} needs at least one value, got {getattr(self, name)!r}")
        object.__setattr__(self, "populations", tuple(check_int("populations", p) for p in self.populations))
        for name in ("goal_weights", "behind_weights"):
            values = tuple(
                check_float(name, w, 0.0, open_low=name == "goal_weights") for w in getattr(self, name)
            )
            object.__setattr__(self, name, values)
        check_float("success", self.success, 0.0, open_low=True)


def sized(plan: PlanConfig, population: int, goal_weight: float, behind_weight: float) -> PlanConfig:
    """``plan`` with population P, 10 % elites (at least 2, at most P), goal weight w_g and shaping weight w_b."""
    sampling = replace(
        plan.action.sampling, population=population, elites=min(max(population // 10, 2), population)
    )
    return replace(
        plan,
        action=replace(plan.action, sampling=sampling),
        goal_weight=goal_weight,
        behind_weight=behind_weight,
    )


def _setting(config: Config, population: int, goal_weight: float, weight: float) -> dict[str, Any]:
    plan = sized(config.plan, population, goal_weight, weight)
    env = gymnasium.make(ENV_ID)
    episodes = [simulator_episode(env, plan, config.seed + g, config.steps) for g in range(config.goals)]
    env.close()
    final = np.array([e.final_planar for e in episodes])
    out = {
        "population": population,
        "goal_weight": goal_weight,
        "behind_weight": weight,
        "final_planar": final.tolist(),
        "start_planar": [e.start_planar for e in episodes],
        "median_final": float(np.median(final)),
        "success": float(np.mean(final <= config.success)),
        "moved_share": float(np.mean([e.moved > MOVED for e in episodes])),
        "min_tip_object_median": float(np.median([e.min_tip_object for e in episodes])),
        "step_cpu_seconds": float(np.median([e.cpu for e in episodes if e.cpu is not None])),
    }
    log.info(
        "pusher-ceiling P=%d w_g=%g w_b=%g: median final %.3f m",
        population,
        goal_weight,
        weight,
        out["median_final"],
    )
    return out


QUICK = Config(goals=2, steps=30, populations=(32,), goal_weights=(PLAN.goal_weight,))
TINY = Config(
    goals=1,
    steps=2,
    plan=replace(
        PLAN, action=replace(PLAN.action, horizon=2, sampling=replace(PLAN.action.sampling, iterations=1))
    ),
    populations=(4,),
    goal_weights=(PLAN.goal_weight,),
)


@register("pusher-ceiling", config=Config, quick=QUICK, tiny=TINY)
def run(config: Config, progress_bar: bool = False) -> Report:
    """Pusher-v5 with the planner on the true simulator: final distance and step time per population and shaping."""
    with torch_threads(config.threads):
        rows = [
            _setting(config, p, g, w)
            for w in config.behind_weights
            for g in config.goal_weights
            for p in config.populations
        ]
    chosen = (config.plan.action.sampling.population, config.plan.goal_weight, config.plan.behind_weight)
    default = next(
        (r for r in rows if (r["population"], r["goal_weight"], r["behind_weight"]) == chosen), None
    )
    full = config.goals >= 20 and config.steps == 100
    return Report(
        title="Pusher-v5 with a perfect model: the planner's ceiling per population, goal and shaping weight",
        metrics={"settings": rows, "chosen": default},
        tables=[
            Table(
                "Final object-goal distance (x-y) of MPC on the true simulator",
                [
                    "population",
                    "goal weight",
                    "behind weight",
                    "median final [m]",
                    f"share within {config.success} m",
                    "share moved",
                    "min tip-object, median [m]",
                    "planning CPU s / step",
                ],
                [
                    [
                        r["population"],
                        r["goal_weight"],
                        r["behind_weight"],
                        r["median_final"],
                        r["success"],
                        r["moved_share"],
                        r["min_tip_object_median"],
                        r["step_cpu_seconds"],
                    ]
                    for r in rows
                ],
                caption=f"{config.goals} goals x {config.steps} steps per setting, horizon "
                f"{config.plan.action.horizon}, {config.plan.action.sampling.iterations} iterations.",
            )
        ],
        targets=[
            Target(
                "ceiling_median_final",
                None if default is None else default["median_final"],
                0.10,
                "<=",
                "median final distance of the pusher experiment's planner settings with a perfect model, m",
                Precondition(
                    full and default is not None,
                    f">= 20 goals of 100 steps with the chosen population and weights "
                    f"(this run: {config.goals} goals of {config.steps} steps)",
                ),
            )
        ],
        notes=[
            "Goal g resets Pusher-v5 with seed + g; the same goals for every setting.",
            "No learning: the model is MuJoCo itself from the exact state, so the gap to the goal is the planner's.",
        ],
    )
