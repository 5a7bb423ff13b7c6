"""The PETS-style baseline as an aggregation learner: its own episodes, its data, warm refits.

:class:`PetsLearner` keeps one :class:`pal.baselines.pets.ProbabilisticEnsemble` for the whole
run and refits it after each episode on all transitions so far, starting from its current weights
(the input and output standardisation is recomputed on the grown data, as mbrl-lib's
normaliser is); the CEM planner plans through it. It is driven by
:func:`pal.agent.aggregate.run_rounds`, the same loop as the agent, so both get the same
rounds, episode seeds and environment steps.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import gymnasium
import numpy as np

from pal.agent.aggregate import Exploration, Rollout, derived_seed, parameter_digest, recorded
from pal.agent.config import PlanConfig
from pal.baselines.pets import BaselineConfig, CEMPlanner, Cost, ProbabilisticEnsemble, act_together

__all__ = ["PetsEpisode", "PetsLearner"]


@dataclass
class PetsEpisode:
    """One episode of the baseline.

    Attributes:
        observations: (T + 1, D) the observations from the reset on.
        predicted: (T, D) at each step, the planned sequence's predicted final observation
            (empty for random actions).
        cpu, wall: (T,) planning time per step, s (empty for random actions).
    """

    observations: np.ndarray
    predicted: np.ndarray
    cpu: list[float] = field(default_factory=list)
    wall: list[float] = field(default_factory=list)


class PetsLearner:
    """The baseline on its own environment (module docstring).

    Args:
        env: its environment (1-D Box observation and action spaces).
        config: the ensemble and its training.
        plan: the planner settings (shared with the agent).
        cost: the step cost ``(obs (..., D), act (..., A)) -> (...)``.
        seed: weights, bootstraps, the planner's samples and the random actions.
    """

    def __init__(
        self, env: gymnasium.Env, config: BaselineConfig, plan: PlanConfig, cost: Cost, seed: int = 0
    ) -> None:
        self.env = env
        self.low = np.asarray(env.action_space.low, dtype=np.float64)
        self.high = np.asarray(env.action_space.high, dtype=np.float64)
        dim = int(np.prod(env.observation_space.shape))
        self.model = ProbabilisticEnsemble(dim, len(self.low), config, seed=seed)
        self.planner = CEMPlanner(self.model, self.low, self.high, plan, cost, seed=seed + 1)
        self.rng = np.random.default_rng(np.random.SeedSequence([seed, 5]))
        self.data: tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]] = ([], [], [])
        self.fitted = False
        self._digest: tuple[float, ...] | None = None

    def run(
        self,
        env: gymnasium.Env,
        seed: int,
        steps: int,
        random: bool,
        record: bool,
        exploration: Exploration | None = None,
    ) -> PetsEpisode:
        """Up to ``steps`` steps on ``env`` from ``reset(seed=seed)``; ``record`` appends the transitions to the data.

        ``exploration`` perturbs the planner's actions (:meth:`pal.agent.aggregate.Exploration.offsets`).
        """
        obs, _ = env.reset(seed=seed)
        offsets = None if exploration is None else exploration.offsets(seed, steps, self.low, self.high)
        path, pred, cpu, wall = [np.asarray(obs, dtype=np.float64)], [], [], []
        self.planner.reset()
        for t in range(steps):
            o = path[-1]
            if random or not self.fitted:
                a = self.rng.uniform(self.low, self.high)
            else:
                c0, w0 = time.process_time(), time.perf_counter()
                a, final = self.planner.act(o)
                cpu.append(time.process_time() - c0)
                wall.append(time.perf_counter() - w0)
                pred.append(final)
                if offsets is not None:
                    a = np.clip(a + offsets[t], self.low, self.high)
            terminated = self._step(env, o, a, path, record)
            if terminated:
                break
        predicted = np.stack(pred) if pred else np.zeros((0, len(path[0])))
        return PetsEpisode(np.stack(path), predicted, cpu, wall)

    def run_together(
        self, envs: Sequence[gymnasium.Env], seeds: Sequence[int], steps: int
    ) -> list[PetsEpisode]:
        """:meth:`run` of evaluation episodes (nothing recorded, no exploration) on ``envs``, in lockstep.

        One planner per episode over the current ensemble; at each step the planners of the
        episodes that go on search together (:func:`pal.baselines.pets.act_together`). The
        episodes' ``cpu`` and ``wall`` stay empty: a step of the batch is not one planner's step.
        Before the first fit the episodes run one after the other with random torques, as :meth:`run`.
        """
        if not self.fitted:
            return [self.run(env, s, steps, False, False) for env, s in zip(envs, seeds, strict=True)]
        p = self.planner
        planners = [
            CEMPlanner(self.model, self.low, self.high, p.config, p.cost, seed=derived_seed(s, 81))
            for s in seeds
        ]
        paths = [
            [np.asarray(env.reset(seed=s)[0], dtype=np.float64)] for env, s in zip(envs, seeds, strict=True)
        ]
        preds: list[list[np.ndarray]] = [[] for _ in envs]
        live = list(range(len(envs)))
        for _ in range(steps):
            acted = act_together([planners[k] for k in live], np.stack([paths[k][-1] for k in live]))
            ended = set()
            for k, (a, final) in zip(live, acted, strict=True):
                preds[k].append(final)
                if self._step(envs[k], paths[k][-1], a, paths[k], False):
                    ended.add(k)
            live = [k for k in live if k not in ended]
            if not live:
                break
        return [
            PetsEpisode(np.stack(path), np.stack(pred), [], [])
            for path, pred in zip(paths, preds, strict=True)
        ]

    def _step(self, env: gymnasium.Env, o: np.ndarray, a: np.ndarray, path: list, record: bool) -> bool:
        """Step ``env`` with ``a`` from observation ``o``; append to ``path`` (and the data); True when it ended."""
        obs, _, terminated, truncated, _ = env.step(a.astype(np.float32))
        path.append(np.asarray(obs, dtype=np.float64))
        if record:
            for store, x in zip(self.data, (o, a, path[-1]), strict=True):
                store.append(x)
        return bool(terminated or truncated)

    def episode(self, seed: int, steps: int, random: bool, exploration: Exploration | None = None) -> Rollout:
        """One training episode on its environment (:class:`pal.agent.aggregate.Learner`), with its trace."""
        e = self.run(self.env, seed, steps, random, record=True, exploration=exploration)
        return recorded(self.env, Rollout(len(e.observations) - 1, e))

    def branch(self, seed: int, state: np.ndarray, actions: np.ndarray) -> int:
        """Execute ``actions`` (K, A) from the restored ``state`` into the data (:class:`pal.agent.aggregate.BranchingLearner`)."""
        obs, _ = self.env.reset(seed=seed, options={"state": state})
        path = [np.asarray(obs, dtype=np.float64)]
        for a in np.clip(np.asarray(actions, dtype=np.float64), self.low, self.high):
            if self._step(self.env, path[-1], a, path, record=True):
                break
        return len(path) - 1

    def refit(self) -> bool:
        """Refit the ensemble on all data from its current weights (:class:`pal.agent.aggregate.Learner`)."""
        warm = self._digest is not None and parameter_digest(self.model) == self._digest
        obs, act, nxt = (np.stack(x) for x in self.data)
        self.model.fit(obs, act, nxt)
        self.fitted = True
        self._digest = parameter_digest(self.model)
        return warm
