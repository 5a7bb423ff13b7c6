"""The episodes of the ``pusher`` experiment: the agent, the PETS-style baseline and random actions on Pusher-v5.

Every controller works on its own ``gymnasium.make("Pusher-v5")`` and is judged by what the
environment reports: the object's and the goal's positions in the observation. A shared
:class:`Transitions` wrapper records the full observations of the agent's babbling, so the
baseline learns from exactly the same first transitions; after that each learns from its own
episodes (data aggregation, as PETS does), with the same number of environment steps.

The step cost both planners minimise, per step, with ``p`` the object, ``g`` the goal and ``e``
the fingertip (3-D, m) and ``a`` the torques:

    c = w_g c(p - g) + w_e c(e - p) + w_b c(e_xy - behind(p, g)) + w_a |a|^2

(the agent's :func:`pal.agent.plan.preference` with ``scale=1``, ``target_at="every"``; the
form of ``c`` and the weights from :class:`pal.agent.PlanConfig`: PETS's L1 cost with 1.25,
0.5, 0 and 0.1 by default).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import gymnasium
import numpy as np
import torch

from pal.agent import Agent
from pal.agent.config import PlanConfig
from pal.agent.plan import behind, distance
from pal.baselines.pets import BaselineConfig, CEMPlanner, ProbabilisticEnsemble

__all__ = [
    "ENV_ID",
    "Episode",
    "Transitions",
    "agent_episode",
    "baseline_episode",
    "distances",
    "random_episode",
    "step_cost",
]

#: Gymnasium's id of the benchmark task.
ENV_ID = "Pusher-v5"
_TIP, _OBJ, _GOAL = slice(14, 17), slice(17, 20), slice(20, 23)


class Transitions(gymnasium.Wrapper):
    """Records ``(observation, action, next observation)`` of every step (the baseline's data)."""

    def __init__(self, env: gymnasium.Env) -> None:
        super().__init__(env)
        self.obs: list[np.ndarray] = []
        self.act: list[np.ndarray] = []
        self.nxt: list[np.ndarray] = []
        self._last: np.ndarray | None = None

    def reset(self, **kwargs: Any) -> tuple[np.ndarray, dict[str, Any]]:
        """Reset the wrapped environment and remember its first observation."""
        obs, info = self.env.reset(**kwargs)
        self._last = np.asarray(obs, dtype=np.float64)
        return obs, info

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        """Step the wrapped environment and record the transition."""
        obs, reward, terminated, truncated, info = self.env.step(action)
        self.obs.append(self._last)
        self.act.append(np.asarray(action, dtype=np.float64))
        self.nxt.append(np.asarray(obs, dtype=np.float64))
        self._last = np.asarray(obs, dtype=np.float64)
        return obs, reward, terminated, truncated, info

    def arrays(self, n: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The first ``n`` (default all) transitions: ``(N, 23)``, ``(N, 7)``, ``(N, 23)``."""
        n = len(self.obs) if n is None else n
        return np.stack(self.obs[:n]), np.stack(self.act[:n]), np.stack(self.nxt[:n])


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
        cpu, wall: planning time per step (process CPU, wall clock).
        path: (T + 1, 2) object x-y; goal: (2,) goal x-y.
    """

    final_planar: float
    final_distance: float
    start_planar: float
    predicted_final: float | None = None
    cpu: float | None = None
    wall: float | None = None
    path: list[list[float]] = field(default_factory=list)
    goal: list[float] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        """JSON-compatible fields (without the path)."""
        return {k: v for k, v in self.__dict__.items() if k not in ("path", "goal")}


def _finish(
    obs0: np.ndarray, obs: np.ndarray, path: list, pred: float | None, cpu: list, wall: list
) -> Episode:
    planar, full = distances(obs)
    return Episode(
        planar,
        full,
        distances(obs0)[0],
        pred,
        float(np.mean(cpu)) if cpu else None,
        float(np.mean(wall)) if wall else None,
        [list(map(float, p)) for p in path],
        list(map(float, np.asarray(obs0)[_GOAL][:2])),
    )


def _observation(percept: Any) -> np.ndarray:
    """The Pusher observation layout (23,) rebuilt from the agent's percept."""
    p = percept
    return np.concatenate([p.q, p.v, p.effector, p.measurements["object"].position, p.goals["object"]])


def agent_episode(agent: Agent, seed: int, steps: int, horizon: int) -> Episode:
    """The agent in goal mode (MPC towards the observed goal) for ``steps`` steps from ``reset(seed)``."""
    percept = agent.reset(seed=seed)
    obs0 = _observation(percept)
    path, cpu, wall, pred = [obs0[_OBJ][:2]], [], [], None
    for t in range(steps):
        c0, w0 = time.process_time(), time.perf_counter()
        decision = agent.decide("goal")
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - w0)
        if t == max(steps - horizon, 0) and decision.predicted:
            goal = agent.percept.goals["object"]
            pred = float(np.linalg.norm((decision.predicted["object"] - goal)[:2]))
        percept = agent.step(decision.action)
        path.append(percept.measurements["object"].position[:2])
    obs = _observation(percept)
    return _finish(obs0, obs, path, pred, cpu, wall)


def baseline_episode(env: gymnasium.Env, planner: CEMPlanner, seed: int, steps: int) -> Episode:
    """The PETS-style baseline for ``steps`` steps from ``env.reset(seed=seed)``."""
    obs, _ = env.reset(seed=seed)
    obs0 = np.asarray(obs, dtype=np.float64)
    planner.reset()
    path, cpu, wall, pred = [obs0[_OBJ][:2]], [], [], None
    horizon = planner.config.action.horizon
    for t in range(steps):
        c0, w0 = time.process_time(), time.perf_counter()
        action, final = planner.act(np.asarray(obs, dtype=np.float64))
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - w0)
        if t == max(steps - horizon, 0):
            pred = float(np.linalg.norm((final[_OBJ] - final[_GOAL])[:2]))
        obs, *_ = env.step(action.astype(np.float32))
        path.append(np.asarray(obs)[_OBJ][:2])
    return _finish(obs0, np.asarray(obs, dtype=np.float64), path, pred, cpu, wall)


def random_episode(env: gymnasium.Env, seed: int, steps: int) -> Episode:
    """Uniform random torques for ``steps`` steps from ``env.reset(seed=seed)``."""
    obs, _ = env.reset(seed=seed)
    obs0 = np.asarray(obs, dtype=np.float64)
    rng = np.random.default_rng(seed)
    space = env.action_space
    path = [obs0[_OBJ][:2]]
    for _ in range(steps):
        obs, *_ = env.step(rng.uniform(space.low, space.high).astype(np.float32))
        path.append(np.asarray(obs)[_OBJ][:2])
    return _finish(obs0, np.asarray(obs, dtype=np.float64), path, None, [], [])


def fit_baseline(
    data: tuple[np.ndarray, np.ndarray, np.ndarray], config: BaselineConfig, seed: int
) -> ProbabilisticEnsemble:
    """A new PETS-style ensemble fitted on ``(obs, act, next_obs)``."""
    obs, act, nxt = data
    model = ProbabilisticEnsemble(obs.shape[1], act.shape[1], config, seed=seed)
    model.fit(obs, act, nxt)
    return model
