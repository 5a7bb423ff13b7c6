"""Open-loop physics through ``mujoco.rollout``, bit for bit equal to the Python loop.

``mujoco.rollout`` steps a batch of trajectories in C (optionally on a thread pool) from
``mjSTATE_FULLPHYSICS`` initial states, an initial warm start ``qacc_warmstart`` and a
control sequence per trajectory. The recorded states of pal (:data:`~pal.sim.env.STATE_SPEC`)
hold the same physics state plus the warm start, so a recorded state splits into the two
inputs of a rollout, and the outputs join back into recorded states (:func:`split_state`,
:func:`join_state`).

- :class:`BatchReplayer`: one environment step (``frame_skip`` physics steps under a held
  command) from each of B recorded states, all in one rollout. It replaces a loop of
  :func:`pal.sim.babbling.replay` calls and returns the same positions, bit for bit.
- :func:`rollout_steps`: consecutive babbling steps under a precomputed command sequence,
  one rollout call per environment step, so the warm start before every step (part of the
  recorded state) is read back exactly as the Python loop records it.

MuJoCo's rollout stops a trajectory at the first simulator warning (bad qpos/qvel/qacc,
full contact buffer) and repeats its last state, where ``mj_step`` resets the data and goes
on. A trajectory whose time stopped advancing is therefore stepped again by the Python loop,
so the results stay those of the serial path.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import mujoco
import mujoco.rollout
import numpy as np

from pal.sim.env import STATE_SPEC, BabblingEnv

__all__ = ["FULLPHYSICS", "BatchReplayer", "join_state", "rollout_steps", "split_state", "state_layout"]

#: The state signature of ``mujoco.rollout``'s initial and output states.
FULLPHYSICS = int(mujoco.mjtState.mjSTATE_FULLPHYSICS)
_WARMSTART = int(mujoco.mjtState.mjSTATE_WARMSTART)
_BITS = sorted(
    int(v) for k, v in mujoco.mjtState.__members__.items() if k != "mjNSTATE" and int(v) & (int(v) - 1) == 0
)


def state_layout(model: mujoco.MjModel, spec: int = STATE_SPEC) -> dict[int, np.ndarray]:
    """Where each state element lies in a ``spec`` state vector (``mj_getState``'s bit order).

    Returns:
        element bit (``mjSTATE_QPOS``, ...) -> int index array into the ``(mj_stateSize(spec),)`` vector,
        for every bit of ``spec``.
    """
    out, start = {}, 0
    for bit in _BITS:
        if spec & bit:
            size = int(mujoco.mj_stateSize(model, bit))
            out[bit] = np.arange(start, start + size)
            start += size
    return out


def _indices(model: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray]:
    """Indices of the FULLPHYSICS part and of the warm start in a :data:`STATE_SPEC` vector."""
    layout = state_layout(model, STATE_SPEC)
    full = np.concatenate([idx for bit, idx in layout.items() if bit & FULLPHYSICS])
    return full, layout[_WARMSTART]


def split_state(model: mujoco.MjModel, states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(B, S)`` :data:`STATE_SPEC` states -> ``(B, S_full)`` FULLPHYSICS states and ``(B, nv)`` warm starts."""
    full, warm = _indices(model)
    return np.ascontiguousarray(states[:, full]), np.ascontiguousarray(states[:, warm])


def join_state(model: mujoco.MjModel, full_states: np.ndarray, warm: np.ndarray) -> np.ndarray:
    """The inverse of :func:`split_state`: ``(B, S)`` float64 :data:`STATE_SPEC` states."""
    full, warm_idx = _indices(model)
    out = np.empty((len(full_states), len(full) + len(warm_idx)))
    out[:, full] = full_states
    out[:, warm_idx] = warm
    return out


def _check_batch(env: BabblingEnv, states: Any, ctrls: Any) -> tuple[np.ndarray, np.ndarray]:
    s = np.asarray(states, dtype=np.float64)
    if s.ndim != 2 or s.shape[1] != env.state_size:
        raise ValueError(f"states has shape {s.shape}, expected (B, {env.state_size}) get_state() vectors")
    a = np.asarray(ctrls, dtype=np.float64)
    nu = len(env.actuator_ids)
    if a.shape != (len(s), nu):
        raise ValueError(f"ctrls has shape {a.shape}, expected ({len(s)}, {nu}): one command per state")
    if not np.all(np.isfinite(s)):
        raise ValueError("states contain NaN or inf")
    if not np.all(np.isfinite(a)):
        bad = np.flatnonzero(~np.isfinite(a).all(1))
        raise ValueError(f"ctrls rows {bad.tolist()} contain NaN or inf; every command must be finite")
    return s, np.clip(a, env.ctrl_low, env.ctrl_high)


class BatchReplayer:
    """One environment step from each of B recorded states, in one ``mujoco.rollout`` call.

    Equal, bit for bit, to ``[replay(env, s, c) for s, c in zip(states, ctrls)]``: the same
    state and warm start, the same command held for ``frame_skip`` steps, the unselected
    actuators at the environment's current ``data.ctrl``.

    Args:
        env: the environment of the recording (its model, selection and frame skip).
        threads: worker threads of the rollout pool (0: the calling thread only).

    Raises:
        ValueError: ``threads`` < 0.
    """

    def __init__(self, env: BabblingEnv, threads: int = 0) -> None:
        if isinstance(threads, bool) or not isinstance(threads, (int, np.integer)) or threads < 0:
            raise ValueError(f"threads must be an integer >= 0, got {threads!r}")
        self.env, self.threads = env, int(threads)
        self._datas = [mujoco.MjData(env.model) for _ in range(max(1, self.threads))]
        self._pool = mujoco.rollout.Rollout(nthread=self.threads)

    def close(self) -> None:
        """Stop the thread pool."""
        if self._pool is not None:
            self._pool.close()
            self._pool = None

    def __enter__(self) -> BatchReplayer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def step(self, states: Any, ctrls: Any) -> np.ndarray:
        """Positions of the selected joints after one environment step from each state.

        Args:
            states: ``(B, state_size)`` float64 :meth:`~pal.sim.env.BabblingEnv.get_state` vectors.
            ctrls: ``(B, n_actuators)`` commands (clipped to ``ctrlrange`` as ``env.step`` does).

        Returns:
            ``(B, n_joints)`` float64 positions after the step, rad or m.

        Raises:
            ValueError: wrong shapes, or NaN/inf in states or commands.
            RuntimeError: the replayer was closed.
        """
        if self._pool is None:
            raise RuntimeError("this BatchReplayer is closed")
        env = self.env
        s, applied = _check_batch(env, states, ctrls)
        if not len(s):
            return np.empty((0, len(env.qpos_indices)))
        m = env.model
        full, warm = split_state(m, s)
        control = np.tile(env.data.ctrl, (len(s), 1))
        control[:, env.actuator_ids] = applied
        control = np.ascontiguousarray(np.repeat(control[:, None, :], env.frame_skip, axis=1))
        out, _ = self._pool.rollout(m, self._datas, full, control, initial_warmstart=warm)
        q = out[:, -1, 1 + env.qpos_indices]  # FULLPHYSICS: time, qpos, ...
        if env.frame_skip > 1:
            for i in np.flatnonzero(out[:, -1, 0] == out[:, -2, 0]):  # stopped at a warning
                env.set_state(s[i])
                env.data.ctrl[env.actuator_ids] = applied[i]
                mujoco.mj_step(m, env.data, env.frame_skip)
                q[i] = env.data.qpos[env.qpos_indices]
        return q


def rollout_steps(
    env: BabblingEnv, applied: np.ndarray, reset: Callable[[int], bool]
) -> tuple[np.ndarray, np.ndarray]:
    """Consecutive environment steps under precomputed commands, one rollout call per step.

    ``env.data`` is the rollout's data (the calling thread), so after each call it holds what
    ``mj_step`` leaves there in the Python loop, including the warm start of the next step.

    Args:
        env: the environment, in the state before the first step.
        applied: ``(n, n_actuators)`` float64 commands, already clipped.
        reset: called with the row index before each step; it resets ``env`` (and returns
            True) when an episode starts at that row.

    Returns:
        ``(states, after)``: ``(n, state_size)`` :data:`STATE_SPEC` states before each step and
        ``(n, S_full)`` FULLPHYSICS states after it.
    """
    m, d, fs = env.model, env.data, env.frame_skip
    n = len(applied)
    nfull = int(mujoco.mj_stateSize(m, FULLPHYSICS))
    before = np.empty((n, nfull))
    warm = np.empty((n, m.nv))
    after = np.empty((n, nfull))
    out = np.empty((1, fs, nfull))
    control = np.empty((1, fs, m.nu))
    ws = np.empty((1, m.nv))
    pool = mujoco.rollout.Rollout(nthread=0)
    aidx, datas = env.actuator_ids, [d]
    try:
        for i in range(n):
            reset(i)
            mujoco.mj_getState(m, d, before[i], FULLPHYSICS)
            warm[i] = d.qacc_warmstart
            ws[0] = warm[i]
            d.ctrl[aidx] = applied[i]
            control[0] = d.ctrl
            pool.rollout(
                [m],
                datas,
                before[i : i + 1],
                control,
                initial_warmstart=ws,
                state=out,
                skip_checks=True,
                nstep=fs,
            )
            if fs > 1 and out[0, -1, 0] == out[0, -2, 0]:  # stopped at a warning: step as mj_step does
                mujoco.mj_setState(m, d, before[i], FULLPHYSICS)
                d.qacc_warmstart[:] = warm[i]
                mujoco.mj_step(m, d, fs)
                mujoco.mj_getState(m, d, out[0, -1], FULLPHYSICS)
            after[i] = out[0, -1]
    finally:
        pool.close()
    return join_state(m, before, warm), after
