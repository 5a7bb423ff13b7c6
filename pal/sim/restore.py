"""Restarting a Gymnasium MuJoCo environment from a saved simulator state, and recording the states it passes.

:class:`StartFromState` wraps a Gymnasium MuJoCo environment (its unwrapped env has ``model``
and ``data``). Before every step it saves the full physics state (``mujoco.mj_getState`` with
``mjSTATE_FULLPHYSICS``: time, qpos, qvel, act, ... ) and the action, so an episode's states
``(T, S)`` and actions ``(T, A)`` are there at its end; ``reset(options={"state": s})`` continues
from such a state. Gymnasium's observation function is private, so the observation of a restored
state is built by ``observe`` from ``qpos``, ``qvel`` and named body positions (the signature of
:data:`pal.baselines.simulator_mpc.Observe`). Restoring a state is a simulator privilege that a
real body lacks.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import gymnasium
import mujoco
import numpy as np

__all__ = ["StartFromState", "find_wrapper", "full_state"]

_FULL = mujoco.mjtState.mjSTATE_FULLPHYSICS


def full_state(model: mujoco.MjModel, data: mujoco.MjData) -> np.ndarray:
    """The full physics state of ``data``, ``(mj_stateSize(model, mjSTATE_FULLPHYSICS),)``."""
    out = np.empty(mujoco.mj_stateSize(model, _FULL))
    mujoco.mj_getState(model, data, out, _FULL)
    return out


def find_wrapper(env: gymnasium.Env, kind: type) -> Any | None:
    """The outermost wrapper of type ``kind`` around ``env`` (``env`` itself included), or None."""
    current: Any = env
    while current is not None:
        if isinstance(current, kind):
            return current
        current = getattr(current, "env", None)
    return None


class StartFromState(gymnasium.Wrapper):
    """A MuJoCo environment that records its states and restarts from any of them (module docstring).

    Args:
        env: a Gymnasium MuJoCo environment.
        observe: ``(qpos (nq,), qvel (nv,), bodies: name -> (3,)) -> obs`` for a restored state.
        bodies: the bodies whose world positions ``observe`` reads.

    The restored observation reads the body positions of the state itself, while a Gymnasium
    environment's own observation after a step may read them as computed before the step's last
    substep (they then differ by one substep of motion). Every later step is the environment's.
    """

    def __init__(
        self,
        env: gymnasium.Env,
        observe: Callable[[np.ndarray, np.ndarray, dict[str, np.ndarray]], np.ndarray],
        bodies: Sequence[str],
    ) -> None:
        super().__init__(env)
        sim = env.unwrapped
        for name in ("model", "data"):
            if not hasattr(sim, name):
                raise ValueError(f"env {env!r} is not a Gymnasium MuJoCo environment: it has no {name!r}")
        known = {sim.model.body(i).name for i in range(sim.model.nbody)}
        missing = [b for b in bodies if b not in known]
        if missing:
            raise ValueError(f"bodies {missing} are not in the model; known bodies: {sorted(known - {''})}")
        self.observe, self.bodies = observe, tuple(bodies)
        self._states: list[np.ndarray] = []
        self._actions: list[np.ndarray] = []

    @property
    def size(self) -> int:
        """The length S of a state vector."""
        return int(mujoco.mj_stateSize(self.env.unwrapped.model, _FULL))

    @property
    def states(self) -> np.ndarray:
        """``(T, S)`` the states before each step since the last reset."""
        return np.asarray(self._states).reshape(len(self._states), self.size)

    @property
    def actions(self) -> np.ndarray:
        """``(T, A)`` the actions of each step since the last reset."""
        dim = int(np.prod(self.action_space.shape))
        return np.asarray(self._actions, dtype=np.float64).reshape(len(self._actions), dim)

    def step(self, action: Any) -> tuple[Any, Any, bool, bool, dict]:
        """The environment's step, after saving the state and the action."""
        sim = self.env.unwrapped
        self._states.append(full_state(sim.model, sim.data))
        self._actions.append(np.asarray(action, dtype=np.float64).reshape(-1).copy())
        return self.env.step(action)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict]:
        """Reset with ``seed``; then, given ``options["state"]``, restore that state (``(S,)``, finite)."""
        self._states, self._actions = [], []
        options = dict(options or {})
        state = options.pop("state", None)
        obs, info = self.env.reset(seed=seed, options=options or None)
        if state is None:
            return obs, info
        sim = self.env.unwrapped
        s = np.asarray(state, dtype=np.float64)
        if s.shape != (self.size,) or not np.all(np.isfinite(s)):
            raise ValueError(
                f"state has shape {s.shape}; expected a finite full-physics state of shape ({self.size},)"
            )
        mujoco.mj_setState(sim.model, sim.data, s, _FULL)
        mujoco.mj_forward(sim.model, sim.data)
        bodies = {b: sim.data.body(b).xpos.copy() for b in self.bodies}
        return self.observe(sim.data.qpos.copy(), sim.data.qvel.copy(), bodies), info
