"""``BabblingEnv``: a gymnasium environment around any MJCF body, for motor babbling.

One environment step sets the selected actuators' ``ctrl`` to the action and advances the
physics by ``frame_skip`` MuJoCo steps (``0.005 s * 50 = 0.25 s`` for the shipped bodies).

- Observation: ``[q, dq/dt]`` of the selected joints, shape ``(2 * n_joints,)`` float64;
  positions in rad (hinge) or m (slide), velocities per second. The bounds are infinite:
  soft joint limits let q overshoot its range and velocities are unbounded.
- Action: the selected actuators' ``ctrl``, shape ``(n_actuators,)``, a float32 Box over
  each ``ctrlrange`` (``[-inf, inf]`` for an actuator that is not ctrllimited).
  Out-of-range actions are clipped to ``ctrlrange`` before they are written to
  ``data.ctrl``; this is exactly MuJoCo's own clamping of limited controls, made visible
  (``info["ctrl"]`` is the applied command). NaN/inf actions raise ``ValueError``.
  Unselected actuators keep ``ctrl = 0`` (clamped by MuJoCo into their range). Joints and
  actuators are selected by their MuJoCo names; an unnamed actuator is called after the joint
  it drives (:mod:`pal.sim.body_info`), and a selected actuator must drive a selected joint.
- Reward 0, never terminated or truncated: the data source decides when to reset.
- Reset: ``mj_resetData`` (the model's ``qpos0``, zero velocity, time 0), plus, if
  ``reset_noise > 0``, a seeded uniform offset in ``[-reset_noise, reset_noise]`` on each
  selected joint's position. The default ``reset_noise=0`` makes every episode start at
  ``qpos0``, as MIMo's babbling did. ``reset(options={"state": s})`` restores a state
  from :meth:`BabblingEnv.get_state` instead.
- State: :data:`STATE_SPEC` = ``mjSTATE_FULLPHYSICS | mjSTATE_WARMSTART`` (time, qpos,
  qvel, act, actuator history, plugin and plastic state, and the solver's warm start).
  Restoring it and applying the same action reproduces the next step bit for bit.

Importing this module registers :data:`ENV_ID` with gymnasium, so
``gymnasium.make("pal/Babbling-v0", model="arm")`` works and the environment has a spec.
``check_env`` then warns only about the infinite observation bounds and the non-normalised
action space, both deliberate (the action space is the thesis's raw ctrl range X_a).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Sequence
from typing import Any

import gymnasium
import mujoco
import numpy as np
from gymnasium import spaces

from pal.checks import check_int
from pal.sim.bodies import LoadedModel, load_model
from pal.sim.body_info import (
    JOINT_TRANSMISSIONS,
    SCALAR_JOINTS,
    actuator_names,
    driven_joints,
    force_limit_ranges,
    joint_names,
)

__all__ = ["ENV_ID", "STATE_SPEC", "BabblingEnv"]

logger = logging.getLogger(__name__)

#: MuJoCo state signature saved by :meth:`BabblingEnv.get_state`.
STATE_SPEC = int(mujoco.mjtState.mjSTATE_FULLPHYSICS | mujoco.mjtState.mjSTATE_WARMSTART)
#: gymnasium registry id (``gymnasium.make(ENV_ID, model="finger")``).
ENV_ID = "pal/Babbling-v0"


def _select(
    kind: str, requested: Sequence[str] | None, known: list[str], allowed: list[str], why: str
) -> list[str] | None:
    """The requested names checked against ``known`` and ``allowed``, or None when none were requested."""
    if requested is None:
        return None
    if isinstance(requested, str):
        raise ValueError(
            f"{kind}s must be a sequence of names, got the string {requested!r}; use [{requested!r}]"
        )
    requested = list(requested)
    unknown = [n for n in requested if n not in known]
    if unknown:
        raise ValueError(f"unknown {kind} name(s) {unknown}; the model's {kind}s are {known}")
    unsupported = [n for n in requested if n not in allowed]
    if unsupported:
        raise ValueError(f"{kind}(s) {unsupported} cannot be selected ({why}); selectable {kind}s: {allowed}")
    duplicates = sorted({n for n in requested if requested.count(n) > 1})
    if duplicates:
        raise ValueError(f"{kind}(s) {duplicates} selected more than once")
    if not requested:
        raise ValueError(f"no {kind} selected; choose from {allowed}")
    return requested


class BabblingEnv(gymnasium.Env[np.ndarray, np.ndarray]):
    """A MuJoCo body as a gymnasium environment (see the module docstring for the spaces).

    Args:
        model: a body name (``"finger"``, ``"arm"``), a path to any MJCF file, or a
            :class:`~pal.sim.bodies.LoadedModel`.
        joints: names of the observed joints (hinge or slide); default all of them.
        actuators: names of the commanded actuators (see :mod:`pal.sim.body_info` for
            unnamed ones); default every actuator that drives a selected joint. Each must
            drive a selected joint.
        frame_skip: MuJoCo steps per environment step (>= 1).
        reset_noise: half-width of the uniform reset offset on selected joint positions,
            rad or m (>= 0; default 0: reset to ``qpos0`` exactly).

    Raises:
        MJCFError: missing or malformed MJCF file.
        ValueError: unknown joint/actuator names (the message lists the known ones), an
            actuator that drives no selected joint, a bad frame_skip or reset_noise.

    Attributes:
        actuator_force_limits: actuator -> the commands within which no force limit clamps
            its output, or None (:func:`pal.sim.body_info.force_limit_ranges`).
    """

    metadata: dict[str, Any] = {"render_modes": []}  # noqa: RUF012 - gymnasium's class attribute

    def __init__(
        self,
        model: str | os.PathLike[str] | LoadedModel = "finger",
        *,
        joints: Sequence[str] | None = None,
        actuators: Sequence[str] | None = None,
        frame_skip: int = 50,
        reset_noise: float = 0.0,
    ) -> None:
        frame_skip = check_int("frame_skip", frame_skip)
        if not (np.isfinite(reset_noise) and reset_noise >= 0):
            raise ValueError(f"reset_noise must be a finite number >= 0, got {reset_noise!r}")
        self.loaded = model if isinstance(model, LoadedModel) else load_model(model)
        self.model: mujoco.MjModel = self.loaded.model
        self.data = mujoco.MjData(self.model)
        self.frame_skip = int(frame_skip)
        self.reset_noise = float(reset_noise)
        m = self.model

        all_joints = joint_names(m)
        scalar = [n for i, n in enumerate(all_joints) if n and int(m.jnt_type[i]) in SCALAR_JOINTS]
        if not scalar:
            raise ValueError(f"model {self.loaded.name!r} has no hinge or slide joint to observe")
        chosen = _select("joint", joints, [n for n in all_joints if n], scalar, "only hinge and slide joints")
        self.joint_names: tuple[str, ...] = tuple(chosen or scalar)
        all_acts = actuator_names(m)
        drives = dict(zip(all_acts, driven_joints(m), strict=True))
        selected = {all_joints.index(n) for n in self.joint_names}
        driving = [a for a in all_acts if selected & set(drives[a])]
        requested = _select("actuator", actuators, all_acts, all_acts, "")
        if requested is not None:
            idle = [a for a in requested if a not in driving]
            if idle:
                where = {a: [all_joints[j] for j in drives[a]] for a in idle}
                raise ValueError(
                    f"actuator(s) {idle} drive no selected joint (they drive {where}; selected joints: "
                    f"{list(self.joint_names)}); select their joints (--joint) or drop them"
                )
        elif not driving:
            raise ValueError(
                f"no actuator of model {self.loaded.name!r} drives the selected joints {list(self.joint_names)}; "
                f"its actuators are {all_acts}"
            )
        self.actuator_names: tuple[str, ...] = tuple(requested or driving)

        jids = [all_joints.index(n) for n in self.joint_names]
        self.joint_ids = np.array(jids, dtype=np.intp)
        self.qpos_indices = np.array([m.jnt_qposadr[j] for j in jids], dtype=np.intp)
        self.qvel_indices = np.array([m.jnt_dofadr[j] for j in jids], dtype=np.intp)
        self.actuator_ids = np.array([all_acts.index(n) for n in self.actuator_names], dtype=np.intp)
        limited = m.actuator_ctrllimited[self.actuator_ids].astype(bool)
        rng = m.actuator_ctrlrange[self.actuator_ids]
        self.ctrl_low = np.where(limited, rng[:, 0], -np.inf)
        self.ctrl_high = np.where(limited, rng[:, 1], np.inf)
        self.joint_actuators: dict[str, str] = self._map_joint_actuators(all_joints)
        limits = force_limit_ranges(m)
        self.actuator_force_limits: dict[str, tuple[float, float] | None] = {
            n: limits[int(i)] for n, i in zip(self.actuator_names, self.actuator_ids, strict=True)
        }

        n = len(self.joint_names)
        self.observation_space = spaces.Box(-np.inf, np.inf, shape=(2 * n,), dtype=np.float64)
        self.action_space = spaces.Box(
            self.ctrl_low.astype(np.float32), self.ctrl_high.astype(np.float32), dtype=np.float32
        )
        self.state_size = int(mujoco.mj_stateSize(m, STATE_SPEC))
        mujoco.mj_forward(m, self.data)

    def _map_joint_actuators(self, all_joints: list[str]) -> dict[str, str]:
        """Map each joint name to the name of the selected actuator whose transmission is that joint."""
        m, out = self.model, {}
        for aid, aname in zip(self.actuator_ids, self.actuator_names, strict=True):
            if int(m.actuator_trntype[aid]) not in JOINT_TRANSMISSIONS:
                continue
            jname = all_joints[int(m.actuator_trnid[aid, 0])]
            if jname in self.joint_names:
                if jname in out:
                    logger.warning(
                        "joint %r is driven by %r and %r; act.%s records %r",
                        jname,
                        out[jname],
                        aname,
                        jname,
                        out[jname],
                    )
                    continue
                out[jname] = aname
        return out

    # ------------------------------------------------------------------ gymnasium API
    def _obs(self) -> np.ndarray:
        return np.concatenate([self.data.qpos[self.qpos_indices], self.data.qvel[self.qvel_indices]])

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Reset to ``qpos0`` (plus seeded noise), or to ``options["state"]``.

        Returns:
            ``(observation, info)``; ``info["time"]`` is the simulation time in s.
        """
        super().reset(seed=seed)
        options = dict(options or {})
        unknown = sorted(set(options) - {"state"})
        if unknown:
            raise ValueError(f"unknown reset option(s) {unknown}; the only option is 'state'")
        if "state" in options:
            self.set_state(options["state"])
        else:
            mujoco.mj_resetData(self.model, self.data)
            if self.reset_noise > 0:
                noise = self.np_random.uniform(
                    -self.reset_noise, self.reset_noise, size=len(self.qpos_indices)
                )
                self.data.qpos[self.qpos_indices] += noise
            mujoco.mj_forward(self.model, self.data)
        return self._obs(), {"time": float(self.data.time)}

    def check_action(self, action: Any) -> np.ndarray:
        """Validate an action and clip it to ``ctrlrange``.

        Args:
            action: array-like of shape ``(n_actuators,)``.

        Returns:
            The applied command, float64 ``(n_actuators,)``.

        Raises:
            ValueError: wrong shape, or NaN/inf entries.
        """
        a = np.asarray(action, dtype=np.float64)
        nu = len(self.actuator_ids)
        if a.shape != (nu,):
            raise ValueError(
                f"action has shape {a.shape}, expected ({nu},) for actuators {list(self.actuator_names)}"
            )
        if not np.all(np.isfinite(a)):
            raise ValueError(f"action {a.tolist()} contains NaN or inf; every entry must be finite")
        return np.clip(a, self.ctrl_low, self.ctrl_high)

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """Apply ``action`` for ``frame_skip`` MuJoCo steps.

        Returns:
            ``(observation, 0.0, False, False, info)`` with ``info["ctrl"]`` the applied
            (clipped) command and ``info["time"]`` the simulation time in s.
        """
        ctrl = self.check_action(action)
        self.data.ctrl[self.actuator_ids] = ctrl
        mujoco.mj_step(self.model, self.data, nstep=self.frame_skip)
        return self._obs(), 0.0, False, False, {"ctrl": ctrl, "time": float(self.data.time)}

    # ------------------------------------------------------------------ state
    def get_state(self, out: np.ndarray | None = None) -> np.ndarray:
        """The full physics state (:data:`STATE_SPEC`), float64 ``(state_size,)``.

        Args:
            out: optional preallocated float64 array of shape ``(state_size,)`` to fill.
        """
        if out is None:
            out = np.empty(self.state_size, dtype=np.float64)
        mujoco.mj_getState(self.model, self.data, out, STATE_SPEC)
        return out

    def set_state(self, state: Any) -> None:
        """Restore a state from :meth:`get_state` (derived quantities are recomputed).

        Raises:
            ValueError: wrong shape or non-finite entries.
        """
        s = np.asarray(state, dtype=np.float64)
        if s.shape != (self.state_size,):
            raise ValueError(
                f"state has shape {s.shape}, expected ({self.state_size},) for model {self.loaded.name!r} "
                f"(signature mjSTATE_FULLPHYSICS|mjSTATE_WARMSTART)"
            )
        if not np.all(np.isfinite(s)):
            raise ValueError("state contains NaN or inf")
        mujoco.mj_setState(self.model, self.data, np.ascontiguousarray(s), STATE_SPEC)
        mujoco.mj_forward(self.model, self.data)  # leaves qacc_warmstart untouched

    @property
    def joint_ranges(self) -> dict[str, tuple[float, float] | None]:
        """Joint limits: name -> (low, high) in rad or m, or None for an unlimited joint."""
        m = self.model
        return {
            n: (float(m.jnt_range[j, 0]), float(m.jnt_range[j, 1])) if m.jnt_limited[j] else None
            for n, j in zip(self.joint_names, self.joint_ids, strict=True)
        }

    @property
    def actuator_ranges(self) -> dict[str, tuple[float, float]]:
        """Actuator ctrl ranges: name -> (low, high) (infinite when not ctrllimited)."""
        return {
            n: (float(lo), float(hi))
            for n, lo, hi in zip(self.actuator_names, self.ctrl_low, self.ctrl_high, strict=True)
        }

    @property
    def dt(self) -> float:
        """Duration of one environment step, s."""
        return float(self.model.opt.timestep) * self.frame_skip


if ENV_ID not in gymnasium.registry:
    gymnasium.register(id=ENV_ID, entry_point="pal.sim.env:BabblingEnv")
