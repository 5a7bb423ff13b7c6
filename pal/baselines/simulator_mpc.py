"""The planner's ceiling: model-predictive control with the true simulator as its model.

:class:`SimulatorMPC` plans exactly as the learners do (the same iCEM / CEM search,
:func:`inference.planning.cross_entropy_search`, the same horizon H, warm start and step cost),
but predicts each candidate sequence with MuJoCo itself, from the environment's exact state:

    s_0 = the environment's full physics state now,
    s_{t+1} = mj_step^k(s_t, a_t)          (k = the environment's frame skip, a_t held k steps)
    L(a) = sum_{t=1..H} c(obs(s_t), a_{t-1})

so its prediction error is zero. What it reaches bounds what any learned model can reach with
these planner settings, cost and episode length: a learner's gap to it is the model's, its gap
to the task's goal is the planner's. The candidates are rolled out in one call of
:func:`mujoco.rollout.rollout` (C, no Python per step). The observation of a state is built from
``qpos``, ``qvel`` and the positions of named bodies (MuJoCo ``framepos`` sensors added to a copy
of the environment's model, which does not change its dynamics).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import gymnasium
import mujoco
import numpy as np
import torch
from mujoco import rollout as mj_rollout
from torch import Tensor

from inference.planning import cross_entropy_search, shift_plan
from pal.agent.config import PlanConfig
from pal.agent.replan import Replanning
from pal.sim.restore import full_state

__all__ = ["PUSHER_BODIES", "Observe", "SimulatorMPC", "pusher_observation"]

#: The bodies whose positions Pusher-v5's observation reads (fingertip, object, goal).
PUSHER_BODIES = ("tips_arm", "object", "goal")

#: ``(qpos (R, H, nq), qvel (R, H, nv), bodies: name -> (R, H, 3)) -> obs (R, H, D)``.
Observe = Callable[[np.ndarray, np.ndarray, dict[str, np.ndarray]], np.ndarray]


def pusher_observation(qpos: np.ndarray, qvel: np.ndarray, bodies: dict[str, np.ndarray]) -> np.ndarray:
    """Pusher-v5's observation (23,) per state: joint angles 0-6, velocities 7-13, fingertip, object, goal."""
    return np.concatenate(
        [qpos[..., :7], qvel[..., :7], bodies["tips_arm"], bodies["object"], bodies["goal"]], axis=-1
    )


class SimulatorMPC:
    """MPC through the environment's own MuJoCo model (module docstring).

    Args:
        env: a Gymnasium MuJoCo environment (its unwrapped env has ``model``, ``data``,
            ``fullpath`` and ``frame_skip``); the planner reads its state at every :meth:`act`.
        config: ``action.horizon``, ``action.sampling``, ``warm_start``, ``replan_every`` (the learners').
        cost: ``(obs (..., D), act (..., A)) -> (...)`` step cost.
        observe: the observation of rolled-out states (e.g. :func:`pusher_observation`).
        bodies: the bodies whose positions ``observe`` reads.
        seed: the search's only source of randomness.
    """

    def __init__(
        self,
        env: gymnasium.Env,
        config: PlanConfig,
        cost: Callable[[Tensor, Tensor], Tensor],
        observe: Observe,
        bodies: Sequence[str],
        seed: int = 0,
    ) -> None:
        sim = env.unwrapped
        for name in ("model", "data", "fullpath", "frame_skip"):
            if not hasattr(sim, name):
                raise ValueError(f"env {env!r} is not a Gymnasium MuJoCo environment: it has no {name!r}")
        self.sim, self.config, self.cost, self.observe = sim, config, cost, observe
        self.bodies = tuple(bodies)
        spec = mujoco.MjSpec.from_file(sim.fullpath)
        known = {b.name for b in spec.bodies}
        missing = [b for b in self.bodies if b not in known]
        if missing:
            raise ValueError(f"bodies {missing} are not in the model; known bodies: {sorted(known - {''})}")
        for b in self.bodies:
            spec.add_sensor(
                type=mujoco.mjtSensor.mjSENS_FRAMEPOS, objtype=mujoco.mjtObj.mjOBJ_XBODY, objname=b
            )
        self.model = spec.compile()
        self.model.opt.timestep = sim.model.opt.timestep
        self.work = mujoco.MjData(self.model)
        self.low = torch.as_tensor(env.action_space.low, dtype=torch.float32)
        self.high = torch.as_tensor(env.action_space.high, dtype=torch.float32)
        self.generator = torch.Generator().manual_seed(seed)
        self._mean: Tensor | None = None
        self._final: np.ndarray | None = None  # the plan's predicted final observation
        self._replan = Replanning(config.replan_every)

    def reset(self) -> None:
        """Forget the warm start (a new episode)."""
        self._mean = None
        self._replan.reset()

    @property
    def plan(self) -> Tensor:
        """The sequence chosen at the last :meth:`act`, ``(H, A)``.

        Raises:
            ValueError: :meth:`act` has not run since the last :meth:`reset`.
        """
        if self._mean is None:
            raise ValueError("no plan yet: call act() first")
        return self._mean

    def state(self) -> np.ndarray:
        """The environment's full physics state now, ``(nstate,)``."""
        return full_state(self.sim.model, self.sim.data)

    def predict(self, state: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """Observations after each step of ``actions`` (R, H, A) from ``state``: ``(R, H, D)``."""
        actions = np.asarray(actions, dtype=np.float64)
        if actions.ndim != 3 or actions.shape[-1] != self.low.shape[0]:
            raise ValueError(f"actions must have shape (R, H, {self.low.shape[0]}), got {actions.shape}")
        k = self.sim.frame_skip
        ctrl = np.repeat(actions, k, axis=1)
        states, sensors = mj_rollout.rollout(self.model, self.work, state, ctrl)
        states, sensors = states[:, k - 1 :: k], sensors[:, k - 1 :: k]
        nq, nv = self.model.nq, self.model.nv
        qpos, qvel = states[..., 1 : 1 + nq], states[..., 1 + nq : 1 + nq + nv]
        bodies = {b: sensors[..., 3 * i : 3 * i + 3] for i, b in enumerate(self.bodies)}
        return self.observe(qpos, qvel, bodies)

    def _loss(self, state: np.ndarray, seqs: Tensor) -> Tensor:
        """Summed step cost of candidate sequences ``(P, H, A)``: ``(P,)``."""
        obs = torch.as_tensor(self.predict(state, seqs.numpy()), dtype=torch.float32)
        return self.cost(obs, seqs).sum(-1)

    def act(self) -> tuple[np.ndarray, np.ndarray]:
        """``(first action (A,), predicted final observation of the plan (D,))`` from the env's state."""
        h = self.config.action.horizon
        if self._mean is not None and self._final is not None and not self._replan.due(h):
            return self._mean[self._replan.take()].numpy().astype(np.float64), self._final.copy()
        state = self.state()
        start = ((self.low + self.high) / 2).expand(1, h, self.low.shape[0]).clone()
        if self.config.warm_start and self._mean is not None:
            start = shift_plan(self._mean, steps=self._replan.shift())[None]

        def objective(a: Tensor) -> Tensor:  # (R, 1, H, A) -> (R, 1)
            return self._loss(state, a[:, 0])[:, None]

        found = cross_entropy_search(
            objective, start, self.low, self.high, self.config.action.sampling, self.generator
        )
        best = found.elites[0, 0]
        self._mean, self._final = best, self.predict(state, best[None].numpy())[0, -1]
        self._replan.planned()
        return best[0].numpy().astype(np.float64), self._final.copy()
