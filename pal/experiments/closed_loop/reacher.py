"""Reaching on Gymnasium's ``Reacher-v5`` through ``Agent(env, reacher_spec())``, beside analytic IK + PD.

Per seed the agent babbles ``babble`` uniform torques (episodes of 50 steps), fits its world
model once (the arm graph with the joint velocity: ``act, q_prev, v_prev -> dq, v``;
``q_prev, dq -> dee``), then runs ``goals`` episodes of ``steps`` steps in the goal mode: MPC
over ``plan.action.horizon`` steps towards the task's own goal, the effector goal of the spec
(no wrapper: the angles come from cos/sin, the fingertip from its position relative to the
goal). Each goal episode runs twice, without and with the online correction from abducted
residuals (:mod:`pal.agent.correction`), from the same seeded reset; the analytic controller
(:class:`pal.baselines.reacher_ik.ReacherIK`) runs from the same resets. Reported: the final
fingertip-goal distance (median, share within 2 cm, max) and the CPU time of one MPC decision
(one torch thread).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import gymnasium
import numpy as np

from pal.agent import Agent, AgentConfig, CorrectionConfig, ModelConfig, PlanConfig, reacher_spec
from pal.agent.config import MODEL_SCHEDULE, PLAN_ACTION, PLAN_SAMPLING
from pal.baselines.reacher_ik import ReacherIK
from pal.checks import check_int
from pal.lab.registry import register
from pal.lab.report import Precondition, Report, Table, Target

__all__ = ["REACH_PLAN", "Config", "run"]

#: MPC for reaching with torques: horizon 5, the distance cost on every step (2 cm scale), iCEM
#: with 64 candidates and no gradient refinement.
REACH_PLAN = PlanConfig(
    action=replace(
        PLAN_ACTION,
        horizon=5,
        target_at="every",
        scale=0.02,
        sampling=replace(PLAN_SAMPLING, population=64, elites=8, refine_steps=0),
    ),
    preference="distance",
)


@dataclass(frozen=True)
class Config:
    """Sizes and settings.

    Attributes:
        seed: first seed (seeds ``seed .. seed + seeds - 1``: babbling, fit, planning, goals).
        seeds: independent agents.
        babble: babbling steps before the fit.
        goals: goal episodes per seed.
        steps: steps per goal episode (Reacher-v5 truncates at 50).
        model: the world model and its fit.
        plan: the MPC settings.
        correction: the correction's settings (run with ``enabled`` off and on).
    """

    seed: int = 0
    seeds: int = 3
    babble: int = 5000
    goals: int = 20
    steps: int = 50
    model: ModelConfig = ModelConfig()
    plan: PlanConfig = REACH_PLAN
    correction: CorrectionConfig = CorrectionConfig(enabled=True)

    def __post_init__(self) -> None:
        check_int("seed", self.seed, minimum=0)
        for name in ("seeds", "babble", "goals"):
            check_int(name, getattr(self, name))
        check_int("steps", self.steps, maximum=50)


def _episode(agent: Agent, seed: int, steps: int, times: list[float]) -> float:
    agent.reset(seed=seed)
    for _ in range(steps):
        t = time.process_time()
        decision = agent.decide("goal")
        times.append(time.process_time() - t)
        agent.step(decision.action)
    p = agent.percept
    return float(np.linalg.norm(p.effector - p.goals[agent.spec.effector_name]))


def _baseline(env: gymnasium.Env, seed: int, steps: int) -> float:
    controller = ReacherIK()
    obs, _ = env.reset(seed=seed)
    for _ in range(steps):
        obs, *_ = env.step(controller(obs).astype(np.float32))
    return float(np.linalg.norm(obs[8:10]))


def _one_seed(config: Config, seed: int) -> dict[str, list[float]]:
    env = gymnasium.make("Reacher-v5")
    try:
        base = AgentConfig(model=config.model, plan=config.plan, reset_every=50)
        learner = Agent(env, reacher_spec(), base, seed=seed)
        learner.run(config.babble, "babble")
        learner.refit()
        out: dict[str, list[float]] = {"plain": [], "corrected": [], "ik": [], "time": []}
        for arm, enabled in (("plain", False), ("corrected", True)):
            cfg = replace(base, reset_every=None, correction=replace(config.correction, enabled=enabled))
            agent = Agent(env, reacher_spec(), cfg, seed=seed, model=learner.model)
            for g in range(config.goals):
                out[arm].append(_episode(agent, 10_000 * (seed + 1) + g, config.steps, out["time"]))
        out["ik"] = [_baseline(env, 10_000 * (seed + 1) + g, config.steps) for g in range(config.goals)]
        return out
    finally:
        env.close()


def _summary(d: np.ndarray) -> dict[str, float]:
    cm = 100.0 * d
    return {
        "median_cm": float(np.median(cm)),
        "within_2cm": float(np.mean(cm < 2.0)),
        "max_cm": float(cm.max()),
    }


@register(
    "reacher",
    config=Config,
    quick=Config(seeds=1, babble=2000, goals=5),
    tiny=Config(
        seeds=1,
        babble=60,
        goals=1,
        steps=2,
        model=ModelConfig(hidden=(8,), members=2, schedule=replace(MODEL_SCHEDULE, epochs=2, patience=None)),
    ),
)
def run(config: Config, progress_bar: bool = False) -> Report:
    """Run the reaching comparison of the module docstring."""
    runs = [_one_seed(config, config.seed + k) for k in range(config.seeds)]
    dist = {arm: np.concatenate([r[arm] for r in runs]) for arm in ("plain", "corrected", "ik")}
    times = np.concatenate([r["time"] for r in runs])
    metrics = {arm: _summary(d) for arm, d in dist.items()}
    metrics["mpc_step_cpu_s"] = float(np.mean(times))
    metrics["finals_cm"] = {arm: (100.0 * d).tolist() for arm, d in dist.items()}
    metrics["episodes"] = len(dist["plain"])
    solvable = Precondition(
        bool(metrics["ik"]["median_cm"] < 0.5), "the IK + PD baseline reaches its goals (median < 0.5 cm)"
    )
    targets = []
    for arm in ("plain", "corrected"):
        m = metrics[arm]
        targets += [
            Target(
                f"median_cm.{arm}", m["median_cm"], 0.5, "<=", f"median final distance, cm ({arm})", solvable
            ),
            Target(
                f"within_2cm.{arm}",
                m["within_2cm"],
                0.95,
                ">=",
                f"share of finals within 2 cm ({arm})",
                solvable,
            ),
        ]
    targets.append(
        Target("mpc_step_cpu_s", metrics["mpc_step_cpu_s"], 0.1, "<=", "CPU s of one MPC decision")
    )
    rows = [
        (arm, m["median_cm"], m["within_2cm"], m["max_cm"])
        for arm, m in ((a, metrics[a]) for a in ("plain", "corrected", "ik"))
    ]
    table = Table(
        "Reacher-v5: final fingertip-goal distance",
        ("controller", "median cm", "within 2 cm", "max cm"),
        rows,
        caption=f"{config.seeds} seed(s) x {config.goals} goals, {config.babble} babbling steps, {config.steps} steps per goal; "
        "plain / corrected: the agent without / with the online correction; ik: analytic IK + PD.",
    )
    notes = [
        f"MPC: horizon {config.plan.action.horizon}, {config.plan.preference} cost on every step, one torch thread."
    ]
    return Report("Reaching on Reacher-v5 through Agent(env, spec)", metrics, [table], targets, notes)
