"""A block of consecutive babbling transitions: commands, joint positions and velocities, simulator states."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["TransitionBlock"]


@dataclass(frozen=True)
class TransitionBlock:
    """Consecutive transitions (n rows, J joints, U actuators, S state entries).

    Attributes:
        ctrl: (n, U) float32 applied commands.
        q_prev, q: (n, J) float64 joint positions before and after each step, rad.
        dq_prev: (n, J) float64 displacement of the step before, q(t-1) - q(t-2), rad
            (0 at the first step of an episode).
        states: (n, S) float64 simulator states before each step.
        step, episode: (n,) int64 global step and episode indices.
        v_prev, v: (n, J) float64 joint velocities (MuJoCo's ``qvel``) before and after each
            step, rad/s (None: not recorded).
    """

    ctrl: np.ndarray
    q_prev: np.ndarray
    q: np.ndarray
    dq_prev: np.ndarray
    states: np.ndarray
    step: np.ndarray
    episode: np.ndarray
    v_prev: np.ndarray | None = None
    v: np.ndarray | None = None
