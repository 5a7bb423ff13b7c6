"""The episodes of the ``pusher`` experiment: the agent, the PETS-style baseline and random actions on Pusher-v5.

Every controller works on its own ``gymnasium.make("Pusher-v5")`` and is judged by what the
environment reports: the fingertip's, the object's and the goal's positions in the observation.
Each learner gathers its own data by aggregation (:mod:`pal.agent.aggregate`), with the same
episode seeds and environment steps; :class:`Episode` is the record both leave, and random
torques too.

The step cost both planners minimise, per step, with ``p`` the object, ``g`` the goal and ``e``
the fingertip (3-D, m) and ``a`` the torques:

    c = w_g c(p - g) + w_e c(e - p) + w_b c(e_xy - behind(p, g)) + w_a |a|^2

(the agent's :func:`pal.agent.plan.preference` with ``scale=1``, ``target_at="every"``; the
form of ``c`` and the weights from :class:`pal.agent.PlanConfig`: in the ``pusher`` experiment
PETS's L1 cost with 12.5 (10x PETS's 1.25), 0.5 and 0, and 0.01 on the torques, a tenth of
PETS's 0.1).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import gymnasium
import numpy as np
import torch

from pal.agent import Agent
from pal.agent.aggregate import Exploration, Rollout, derived_seed
from pal.agent.config import PlanConfig
from pal.agent.decision import Decision
from pal.agent.lockstep import decide_goal_together
from pal.agent.plan import behind, distance
from pal.baselines.pets_aggregate import PetsEpisode
from pal.baselines.simulator_mpc import PUSHER_BODIES, SimulatorMPC, pusher_observation
from pal.sim.restore import StartFromState

__all__ = [
    "ENV_ID",
    "MOVED",
    "Episode",
    "agent_episode",
    "agent_episodes_together",
    "agent_rollout",
    "distances",
    "evaluation_seeds",
    "pets_record",
    "random_episode",
    "roots",
    "simulator_episode",
    "step_cost",
    "training_env",
]

#: Gymnasium's id of the benchmark task.
ENV_ID = "Pusher-v5"
#: An episode moved the object when it left its start by more than this in the table plane, m.
MOVED = 0.005
_TIP, _OBJ, _GOAL = slice(14, 17), slice(17, 20), slice(20, 23)


def evaluation_seeds(seed: int, goals: int) -> list[int]:
    """The reset seeds of a run's ``goals`` evaluation episodes (the ``pusher`` experiment's, from (seed, 91, g))."""
    return [derived_seed(seed, 91, g) for g in range(goals)]


def distances(obs: np.ndarray) -> tuple[float, float]:
    """``(planar, 3-D)`` object-goal distance of an observation, m (3-D is Gymnasium's ``reward_dist``)."""
    o = np.asarray(obs, dtype=np.float64)
    d = o[_OBJ] - o[_GOAL]
    return float(np.linalg.norm(d[:2])), float(np.linalg.norm(d))


def step_cost(config: PlanConfig) -> Any:
    """The baseline's step cost (module docstring): ``(obs (..., 23), act (..., 7)) -> (...)``."""
    kind, scale = config.preference, config.action.scale

    def cost(obs: torch.Tensor, act: torch.Tensor) -> torch.Tensor:
        obj, goal, tip = obs[..., _OBJ], obs[..., _GOAL], obs[..., _TIP]
        c = config.goal_weight * distance(obj - goal, kind, scale)
        c = c + config.effector_weight * distance(tip - obj, kind, scale)
        if config.behind_weight:
            shaped = tip[..., :2] - behind(obj, goal, config.behind_offset)
            c = c + config.behind_weight * distance(shaped, kind, scale)
        return c + config.action_weight * act.pow(2).sum(-1)

    return cost


@dataclass
class Episode:
    """One episode's record (distances in m, times in s per step).

    Attributes:
        final_planar, final_distance: object-goal distance at the end (x-y, and 3-D).
        start_planar: at the start (x-y).
        predicted_final: the plan's predicted x-y distance at its horizon's end, made at the
            step whose horizon ends with the episode (None for random actions).
        cpu, wall: planning time per step (process CPU, wall clock; None for random actions; with
            ``plan.replan_every`` k > 1 the mean over every step, the held ones included).
        path: (T + 1, 2) object x-y; tip: (T + 1, 2) fingertip x-y; goal: (2,) goal x-y.
        min_tip_object: the smallest 3-D fingertip-object distance over the episode.
        moved: the object's largest x-y displacement from its start.
    """

    final_planar: float
    final_distance: float
    start_planar: float
    predicted_final: float | None = None
    cpu: float | None = None
    wall: float | None = None
    path: list[list[float]] = field(default_factory=list)
    tip: list[list[float]] = field(default_factory=list)
    goal: list[float] = field(default_factory=list)
    min_tip_object: float = float("nan")
    moved: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        """JSON-compatible fields (without the paths)."""
        return {k: v for k, v in self.__dict__.items() if k not in ("path", "tip", "goal")}


def _record(observations: np.ndarray, pred: float | None, cpu: list, wall: list) -> Episode:
    """The :class:`Episode` of observations ``(T + 1, 23)``."""
    o = np.asarray(observations, dtype=np.float64)
    planar, full = distances(o[-1])
    obj = o[:, _OBJ]
    return Episode(
        planar,
        full,
        distances(o[0])[0],
        pred,
        float(np.mean(cpu)) if cpu else None,
        float(np.mean(wall)) if wall else None,
        obj[:, :2].tolist(),
        o[:, _TIP][:, :2].tolist(),
        o[0, _GOAL][:2].tolist(),
        float(np.linalg.norm(o[:, _TIP] - obj, axis=1).min()),
        float(np.linalg.norm(obj[:, :2] - obj[0, :2], axis=1).max()),
    )


def _observation(percept: Any) -> np.ndarray:
    """The Pusher observation layout (23,) rebuilt from the agent's percept."""
    p = percept
    return np.concatenate([p.q, p.v, p.effector, p.measurements["object"].position, p.goals["object"]])


def roots(previous: np.ndarray, obs: np.ndarray) -> dict[str, np.ndarray]:
    """The agent's lag-1 roots (:func:`pal.agent.pusher_spec`'s graph) from Pusher-v5 observations (..., 23).

    ``vel_prev.object`` is the object's last displacement, ``obs - previous``.
    """
    return {
        "q_prev": obs[..., :7],
        "v_prev": obs[..., 7:14],
        "ee_prev": obs[..., _TIP],
        "pos_prev.object": obs[..., _OBJ],
        "vel_prev.object": obs[..., _OBJ] - previous[..., _OBJ],
    }


def agent_episode(
    agent: Agent,
    seed: int,
    steps: int,
    horizon: int,
    random: bool = False,
    exploration: Exploration | None = None,
) -> Episode:
    """The agent in goal mode (MPC towards the observed goal), or random torques, for ``steps`` steps from ``reset(seed)``.

    ``exploration`` perturbs the MPC torques (:meth:`pal.agent.aggregate.Exploration.offsets`).
    """
    percept = agent.reset(seed=seed)
    offsets = (
        None if random or exploration is None else exploration.offsets(seed, steps, agent.low, agent.high)
    )
    obs, cpu, wall, pred = [_observation(percept)], [], [], None
    for t in range(steps):
        if random:
            action = agent.random_action()
        else:
            c0, w0 = time.process_time(), time.perf_counter()
            decision = agent.decide("goal")
            cpu.append(time.process_time() - c0)
            wall.append(time.perf_counter() - w0)
            action = decision.action if offsets is None else decision.action + offsets[t]
            if t == max(steps - horizon, 0) and decision.predicted:
                pred = _predicted_final(agent, decision)
        percept = agent.step(action)
        obs.append(_observation(percept))
        if agent.done:
            break
    return _record(np.stack(obs), pred, cpu, wall)


def _predicted_final(agent: Agent, decision: Decision) -> float:
    """The x-y distance to the goal that a plan made ``horizon`` steps before the end predicts for the end, m."""
    goal = agent.percept.goals["object"]
    return float(np.linalg.norm((decision.predicted["object"] - goal)[:2]))


def agent_episodes_together(
    agents: Sequence[Agent], seeds: Sequence[int], steps: int, horizon: int
) -> list[Episode]:
    """:func:`agent_episode` in goal mode for each agent and seed, the agents in lockstep.

    At each step the agents whose episodes go on decide together
    (:func:`pal.agent.lockstep.decide_goal_together`: their plans in one batched search). The
    episodes' ``cpu`` and ``wall`` stay None: a step of the batch is not one agent's MPC step.
    """
    obs = [[_observation(a.reset(seed=s))] for a, s in zip(agents, seeds, strict=True)]
    pred: list[float | None] = [None] * len(agents)
    live = list(range(len(agents)))
    for t in range(steps):
        decisions = decide_goal_together([agents[k] for k in live])
        for k, decision in zip(live, decisions, strict=True):
            if t == max(steps - horizon, 0) and decision.predicted:
                pred[k] = _predicted_final(agents[k], decision)
            obs[k].append(_observation(agents[k].step(decision.action)))
        live = [k for k in live if not agents[k].done]
        if not live:
            break
    return [_record(np.stack(o), p, [], []) for o, p in zip(obs, pred, strict=True)]


def agent_rollout(horizon: int) -> Any:
    """:func:`agent_episode` as the episode of :class:`pal.agent.aggregate.AgentLearner`."""

    def episode(
        agent: Agent, seed: int, steps: int, random: bool, exploration: Exploration | None = None
    ) -> Rollout:
        e = agent_episode(agent, seed, steps, horizon, random, exploration)
        return Rollout(len(e.path) - 1, e)

    return episode


def pets_record(episode: PetsEpisode, horizon: int) -> Episode:
    """The :class:`Episode` of a baseline episode (its prediction made ``horizon`` steps before the end)."""
    pred = None
    if len(episode.predicted):
        final = episode.predicted[max(len(episode.predicted) - horizon, 0)]
        pred = float(np.linalg.norm((final[_OBJ] - final[_GOAL])[:2]))
    return _record(episode.observations, pred, episode.cpu, episode.wall)


def training_env() -> StartFromState:
    """A learner's Pusher-v5 that records its states and actions and restarts from them (for branching)."""
    return StartFromState(gymnasium.make(ENV_ID), pusher_observation, PUSHER_BODIES)


def random_episode(env: gymnasium.Env, seed: int, steps: int) -> Episode:
    """Uniform random torques for ``steps`` steps from ``env.reset(seed=seed)``."""
    obs, _ = env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    space = env.action_space
    path = [np.asarray(obs, dtype=np.float64)]
    for _ in range(steps):
        obs, _, terminated, truncated, _ = env.step(rng.uniform(space.low, space.high).astype(np.float32))
        path.append(np.asarray(obs, dtype=np.float64))
        if terminated or truncated:
            break
    return _record(np.stack(path), None, [], [])


def simulator_episode(env: gymnasium.Env, config: PlanConfig, seed: int, steps: int) -> Episode:
    """MPC with the true simulator as the model (:class:`pal.baselines.simulator_mpc.SimulatorMPC`).

    The same planner settings and step cost as the learners, from ``env.reset(seed=seed)``: the
    planner's ceiling on this task.
    """
    obs, _ = env.reset(seed=seed)
    planner = SimulatorMPC(env, config, step_cost(config), pusher_observation, PUSHER_BODIES, seed=seed)
    path, cpu, wall, pred = [np.asarray(obs, dtype=np.float64)], [], [], None
    for t in range(steps):
        c0, w0 = time.process_time(), time.perf_counter()
        action, final = planner.act()
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - w0)
        if t == max(steps - config.action.horizon, 0):
            pred = float(np.linalg.norm((final[_OBJ] - final[_GOAL])[:2]))
        obs, _, terminated, truncated, _ = env.step(action.astype(np.float32))
        path.append(np.asarray(obs, dtype=np.float64))
        if terminated or truncated:
            break
    return _record(np.stack(path), pred, cpu, wall)
