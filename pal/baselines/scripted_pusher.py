"""The scripted reference of experiment C2: a pushing controller that knows the ground truth.

The module holds the arm's planar kinematics, the approach point of a push, and the controller.

**Kinematics.** The arm moves in the table plane: with shoulder S, heading h = yaw + 90 deg + q1,
the palm centre is ``S + L1 u(h) + L2 u(h + q2)``, with L1 (shoulder to elbow) and L2 (elbow to the
palm centre) read from the compiled model (:attr:`pal.sim.pushing.PushingEnv.link_lengths`; 0.12 and
0.13 m for the shipped arm). :func:`inverse_kinematics` inverts it on the elbow-flexed branch (q2 <= 0).

**Scripted reference (C2).** Each step it reads the box's true pose and the hand's position, and

1. if the box is within ``tolerance`` of the goal, holds;
2. if the hand is behind the box (on the far side from the goal, within ``align`` of the push
   line), pushes it along the goal direction by at most ``max_push`` m;
3. otherwise moves the hand to the approach point behind the box (:func:`approach_point`), via a
   detour around the box when the straight way would cross it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pal.sim.pushing import BOX_HALF as PUSH_BOX_HALF
from pal.sim.pushing import PushingEnv

__all__ = [
    "BOX_HALF",
    "HAND_RADIUS",
    "ScriptedPusher",
    "approach_point",
    "forward_kinematics",
    "inverse_kinematics",
]

#: Half extents of the box's footprint, m.
BOX_HALF = PUSH_BOX_HALF[:2]
#: Radius used for the hand when it pushes, m.
HAND_RADIUS = 0.02


def forward_kinematics(env: PushingEnv, q: np.ndarray) -> np.ndarray:
    """Palm centre (2,) in the table plane for joint angles q = (shoulder, elbow), rad."""
    sx, sy, _ = env.layout.shoulder
    l1, l2 = env.link_lengths
    h = math.radians(env.layout.yaw_deg) + math.pi / 2 + float(q[0])
    return np.array(
        [sx + l1 * math.cos(h) + l2 * math.cos(h + q[1]), sy + l1 * math.sin(h) + l2 * math.sin(h + q[1])]
    )


def inverse_kinematics(env: PushingEnv, point: np.ndarray) -> np.ndarray:
    """Joint angles (2,) that put the palm centre nearest to ``point`` (2,), within the joint ranges."""
    sx, sy, _ = env.layout.shoulder
    l1, l2 = env.link_lengths
    d = np.asarray(point, float) - (sx, sy)
    r = float(np.clip(np.linalg.norm(d), abs(l1 - l2) + 1e-6, l1 + l2 - 1e-6))
    c2 = (r * r - l1 * l1 - l2 * l2) / (2 * l1 * l2)
    q2 = -math.acos(float(np.clip(c2, -1.0, 1.0)))
    bearing = math.atan2(d[1], d[0])
    h = bearing - math.atan2(l2 * math.sin(q2), l1 + l2 * math.cos(q2))
    q1 = (h - math.radians(env.layout.yaw_deg) - math.pi / 2 + math.pi) % (2 * math.pi) - math.pi
    return np.clip(np.array([q1, q2]), env.ctrl_low, env.ctrl_high)


def box_extent(yaw: float, direction: np.ndarray) -> float:
    """Half extent (m) of the box's footprint along the unit ``direction`` when it has yaw ``yaw`` (rad)."""
    phi = math.atan2(direction[1], direction[0]) - yaw
    return BOX_HALF[0] * abs(math.cos(phi)) + BOX_HALF[1] * abs(math.sin(phi))


def approach_point(position: np.ndarray, goal: np.ndarray, reach: float, gap: float = 0.02) -> np.ndarray:
    """Where the hand starts a push of an object at ``position`` towards ``goal``, m.

    The point lies ``reach + gap`` metres behind the object on the push line (``reach`` = the
    object's extent along it plus the hand's).
    """
    e = np.asarray(goal, float) - np.asarray(position, float)
    u = e / max(float(np.linalg.norm(e)), 1e-9)
    return np.asarray(position, float) - u * (reach + gap)


def polar(env: PushingEnv, point: np.ndarray) -> tuple[float, float]:
    """(radius m, bearing rad) of a table point about the shoulder."""
    d = np.asarray(point, float) - np.asarray(env.layout.shoulder[:2])
    return float(np.linalg.norm(d)), math.atan2(d[1], d[0])


def from_polar(env: PushingEnv, radius: float, bearing: float) -> np.ndarray:
    """The table point (2,) at ``radius`` m and ``bearing`` rad about the shoulder."""
    return np.asarray(env.layout.shoulder[:2]) + radius * np.array([math.cos(bearing), math.sin(bearing)])


def wrap(angle: float) -> float:
    """Angle wrapped to [-pi, pi)."""
    return (angle + math.pi) % (2 * math.pi) - math.pi


@dataclass
class ScriptedPusher:
    """The ground-truth reference controller of C2: a geometric pusher that checks its moves in the simulator.

    Each step it reads the box's true pose. If the box is within ``tolerance`` of the goal it holds.
    Otherwise the push starts at :func:`approach_point` behind the box on the line to the goal: if
    the hand is there (within ``align``), it pushes along the line by at most ``max_push`` m.
    Else it chooses a first move among structured candidates (straight to the start; along the
    arc about the shoulder at the start's radius; to the start's radius; tucked in at the hand's or
    the start's bearing; the resting pose) by simulating each followed by a straight move to the
    start, from the saved true state, and keeps the one that ends nearest the start while moving
    the box least (``disturb`` m of box motion cost as much as 1 m of distance). The state is
    restored afterwards. It knows the true state and the true dynamics.

    Attributes:
        env: the world. tolerance, max_push, align, gap (hand-to-box clearance at the start): m.
        disturb: weight of box motion.
    """

    env: PushingEnv
    tolerance: float = 0.005
    max_push: float = 0.03
    align: float = 0.018
    disturb: float = 10.0
    gap: float = 0.03

    def _box(self) -> tuple[np.ndarray, float]:
        pose = self.env.object_poses()["box"]
        return pose[:2, 3].copy(), math.atan2(pose[1, 0], pose[0, 0])

    def _candidates(self, hand: np.ndarray, start: np.ndarray) -> list[tuple[str, np.ndarray]]:
        env = self.env
        _, b_h = polar(env, hand)
        r_s, b_s = polar(env, start)
        turn = wrap(b_s - b_h)
        out = [("reach", inverse_kinematics(env, start))]
        for f in (0.5, 1.0):
            out.append(("arc", inverse_kinematics(env, from_polar(env, r_s, b_h + f * turn))))
        out.append(("radius", inverse_kinematics(env, from_polar(env, r_s, b_h))))
        for b in (b_h, b_s, b_h + 0.5 * turn):
            out.append(("tuck", inverse_kinematics(env, from_polar(env, 0.12, b))))
        out.append(("rest", np.asarray(env.layout.home, float)))
        return out

    def act(self, goal: np.ndarray) -> tuple[np.ndarray, str]:
        """``(action, phase)``: ``"hold"``, ``"push"`` or the chosen approach move (``"reach"``, ``"arc"``, ...)."""
        env = self.env
        goal = np.asarray(goal, float)
        p, yaw = self._box()
        q = env.data.qpos[env.qpos_indices].copy()
        hand = env.hand_position()[:2]
        e = goal - p
        dist = float(np.linalg.norm(e))
        if dist <= self.tolerance:
            return q, "hold"
        u = e / dist
        reach = box_extent(yaw, u) + HAND_RADIUS
        start = approach_point(p, goal, reach, self.gap)
        rel = hand - start
        if (
            abs(float(rel @ np.array([-u[1], u[0]]))) <= self.align
            and -0.02 <= float(rel @ u) <= self.gap + 0.005
        ):
            return inverse_kinematics(env, p - u * reach + u * min(dist, self.max_push)), "push"
        saved = env.get_state()
        best = (np.inf, q, "hold")
        to_start = inverse_kinematics(env, start)
        for phase, a in self._candidates(hand, start):
            env.set_state(saved)
            env.step(a)
            moved = float(np.linalg.norm(self._box()[0] - p))
            near = float(np.linalg.norm(env.hand_position()[:2] - start))
            if near > 0.015:
                env.step(to_start)
                moved = max(moved, float(np.linalg.norm(self._box()[0] - p)))
                near = float(np.linalg.norm(env.hand_position()[:2] - start)) + 0.01
            cost = near + self.disturb * moved
            if cost < best[0]:
                best = (cost, a, phase)
        env.set_state(saved)
        return np.asarray(best[1], float), best[2]
