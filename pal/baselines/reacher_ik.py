"""An analytic controller for Gymnasium's ``Reacher-v5``: inverse kinematics, then a joint PD law.

The two-link planar arm has links ``l1 = 0.1`` m (shoulder to elbow) and ``l2 = 0.11`` m (elbow
to fingertip). For a goal ``(x, y)`` at distance ``r`` from the shoulder

    cos q2 = (r^2 - l1^2 - l2^2) / (2 l1 l2),   q2 = +-acos(.)   (the elbow sign of the arm now)
    q1 = atan2(y, x) - atan2(l2 sin q2, l1 + l2 cos q2)

and the torque command (actuator units, gear 200) is a PD law on the wrapped joint error,

    a = clip(kp (q* - q) - kd qdot, -1, 1).

It reads the task's observation directly (cos/sin of the angles, the goal, the velocities) and
serves as the scale against which the learning agent's reaching is reported.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pal.checks import check_float

__all__ = ["LINKS", "ReacherIK", "inverse_kinematics"]

#: Link lengths of Reacher-v5, m: shoulder to elbow, elbow to fingertip.
LINKS = (0.1, 0.11)


def _wrap(x: np.ndarray) -> np.ndarray:
    return (x + np.pi) % (2 * np.pi) - np.pi


def inverse_kinematics(
    goal: np.ndarray, elbow: float = 1.0, links: tuple[float, float] = LINKS
) -> np.ndarray:
    """Joint angles (2,), rad, that put the fingertip at ``goal`` (2,), m (clipped to the reachable annulus).

    Raises:
        ValueError: a goal that is not a finite (2,).
    """
    g = np.asarray(goal, dtype=np.float64)
    if g.shape != (2,) or not np.all(np.isfinite(g)):
        raise ValueError(f"goal is {goal!r}; expected a finite (2,) in metres")
    l1, l2 = links
    r2 = float(np.clip(g @ g, (l1 - l2) ** 2 + 1e-12, (l1 + l2) ** 2 - 1e-12))
    c2 = np.clip((r2 - l1**2 - l2**2) / (2 * l1 * l2), -1.0, 1.0)
    q2 = np.sign(elbow or 1.0) * np.arccos(c2)
    q1 = np.arctan2(g[1], g[0]) - np.arctan2(l2 * np.sin(q2), l1 + l2 * np.cos(q2))
    return _wrap(np.array([q1, q2]))


@dataclass(frozen=True)
class ReacherIK:
    """The IK + PD controller of the module docstring.

    Attributes:
        kp: proportional gain, actuator units per rad.
        kd: derivative gain, actuator units per rad/s.
    """

    kp: float = 1.0
    kd: float = 0.12

    def __post_init__(self) -> None:
        check_float("kp", self.kp, 0.0, open_low=True)
        check_float("kd", self.kd, 0.0)

    def __call__(self, observation: np.ndarray) -> np.ndarray:
        """The torques (2,) in [-1, 1] for a Reacher-v5 observation (10,).

        Raises:
            ValueError: an observation that is not a finite (10,).
        """
        obs = np.asarray(observation, dtype=np.float64).reshape(-1)
        if obs.shape != (10,) or not np.all(np.isfinite(obs)):
            raise ValueError(f"observation has shape {obs.shape}; expected Reacher-v5's finite (10,)")
        q = np.arctan2(obs[2:4], obs[0:2])
        target = inverse_kinematics(obs[4:6], elbow=q[1])
        return np.clip(self.kp * _wrap(target - q) - self.kd * obs[6:8], -1.0, 1.0)
