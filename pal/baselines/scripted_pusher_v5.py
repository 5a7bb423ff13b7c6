"""A scripted pusher for Gymnasium's Pusher-v5 that reads the true state: episodes in which the arm pushes the object.

Random torques almost never touch Pusher-v5's object (it sits 0.3-0.6 m from the fingertip's
start and the seven torques move the arm around aimlessly), so a model learnt from babbling alone
never sees a push. This controller makes the episodes that do: it moves the fingertip (the body
``tips_arm``, the observation's components 14-16) through four phases, along the push line
``u`` (``towards="outward"``: away from the arm's base, so the approach lies within reach; or
towards the object's goal),

1. ``"over"``: to the approach point ``approach`` m behind the object on the push line, ``lift``
   m above the object's centre;
2. ``"down"``: down to the object's height at that point (once within 2 cm of it);
3. ``"glide"``: along the table at the object's height to the start point ``back`` m behind the
   object (once within 2 cm of its height), so the fingertip is also at the object's height
   away from it, not only while it pushes;
4. ``"push"``: at the object's centre, recomputed every step (once within 2 cm of the start
   point), for at most ``push_steps`` steps or until the fingertip passes the object or slides
   5 cm off the push line; then back to 1.

Each step's torques are those of a Cartesian PD law on the fingertip through the Jacobian of
its position (``mujoco.mj_jacBody``, the arm's seven joints), plus a pull towards a ready
posture q_r (elbow and wrist flexed),

    tau = clip(J^T (k_p (x_target - x) - k_d J qdot) + k_q (q_r - q), -2, 2)   (N m; x in m, q in rad).

From many resets the arm does not reach the approach point and the episode holds no push
(about half of them, e.g. reset seed 0); the others push the object by 1-8 cm. Pusher-v5's object
is very light (7.9e-6 kg) and damped, so a push moves it at most ~3.4 mm per 50 ms step.
"""

from __future__ import annotations

from typing import Any

import mujoco
import numpy as np

from pal.checks import check_choice, check_float, check_int

__all__ = ["PHASES", "ScriptedPusherV5", "scripted_episode"]

#: The arm's ready posture (rad): the elbow and the wrist flexed, so the fingertip can come near the base.
READY = np.array([0.0, 0.3, 0.0, -1.2, 0.0, -0.6, 0.0])
#: The controller's phases, in order.
PHASES = ("over", "down", "glide", "push")


class ScriptedPusherV5:
    """The scripted pusher of the module docstring, on one Pusher-v5 environment.

    Args:
        env: ``gymnasium.make("Pusher-v5")`` or its unwrapped environment; read, never stepped here.
        back: start point of a push behind the object, m. approach: approach point behind it, m.
        lift: height of the approach above it, m.
        towards: the push direction: ``"outward"`` (away from the arm's base, the shoulder: the
            approach point lies between the base and the object, within reach) or ``"goal"``
            (towards the object's goal; the approach point may lie out of reach).
        push_steps: longest push, steps. gain, damping: k_p (N m per m) and k_d (N m s per m).
        posture: k_q, the pull towards the ready posture (N m per rad).

    Raises:
        ValueError: a setting out of range, or an environment without the bodies ``tips_arm``,
            ``object`` and ``goal``.
    """

    def __init__(
        self,
        env: Any,
        back: float = 0.15,
        approach: float = 0.3,
        lift: float = 0.12,
        towards: str = "outward",
        push_steps: int = 25,
        gain: float = 100.0,
        damping: float = 10.0,
        posture: float = 0.5,
    ) -> None:
        raw = getattr(env, "unwrapped", env)
        self.model, self.data = raw.model, raw.data
        names = [self.model.body(i).name for i in range(self.model.nbody)]
        missing = [b for b in ("tips_arm", "object", "goal") if b not in names]
        if missing:
            raise ValueError(f"the environment has no bodies {missing}; expected Gymnasium's Pusher-v5")
        self.back = check_float("back", back, 0.0, open_low=True)
        self.approach = check_float("approach", approach, self.back)
        self.lift = check_float("lift", lift, 0.0)
        self.towards = check_choice("towards", towards, ("outward", "goal"))
        self.push_steps = check_int("push_steps", push_steps)
        self.gain = check_float("gain", gain, 0.0, open_low=True)
        self.damping = check_float("damping", damping, 0.0)
        self.posture = check_float("posture", posture, 0.0)
        self._tip = self.model.body("tips_arm").id
        self._base = np.asarray(self.model.body("r_shoulder_pan_link").pos[:2], dtype=np.float64)
        self._jac = np.zeros((3, self.model.nv))
        self.phase = "over"
        self._steps = 0
        self._line = np.zeros(2)

    def reset(self) -> None:
        """Start a new episode in the ``"over"`` phase."""
        self.phase, self._steps = "over", 0

    def _positions(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        d = self.data
        return (d.body("tips_arm").xpos.copy(), d.body("object").xpos.copy(), d.body("goal").xpos.copy())

    def _torques(self, target: np.ndarray) -> np.ndarray:
        mujoco.mj_jacBody(self.model, self.data, self._jac, None, self._tip)
        jac = self._jac[:, :7]
        x = self.data.xpos[self._tip]
        force = self.gain * (target - x) - self.damping * (jac @ self.data.qvel[:7])
        posture = self.posture * (READY - self.data.qpos[:7])
        return np.clip(jac.T @ force + posture, -2.0, 2.0)

    def _next_phase(
        self, tip: np.ndarray, obj: np.ndarray, points: tuple[np.ndarray, np.ndarray], u: np.ndarray
    ) -> None:
        far, start = points
        if self.phase == "push":
            self._steps += 1
            rel = tip[:2] - obj[:2]
            along = float(rel @ self._line)
            off = float(np.linalg.norm(rel - along * self._line))
            if self._steps > self.push_steps or off > 0.05 or along > 0.0:
                self.phase = "over"
        if self.phase == "over" and np.linalg.norm(tip[:2] - far) < 0.02:
            self.phase = "down"
        if self.phase == "down" and abs(tip[2] - obj[2]) < 0.02:
            self.phase = "glide"
        if self.phase == "glide" and np.linalg.norm(tip[:2] - start) < 0.02:
            self.phase, self._steps, self._line = "push", 0, u

    def act(self) -> tuple[np.ndarray, str]:
        """``(torques (7,) in [-2, 2] N m, phase)`` for the current state (module docstring)."""
        tip, obj, goal = self._positions()
        e = (goal[:2] if self.towards == "goal" else 2 * obj[:2] - self._base) - obj[:2]
        u = e / max(float(np.linalg.norm(e)), 1e-9)
        far, start = obj[:2] - self.approach * u, obj[:2] - self.back * u
        self._next_phase(tip, obj, (far, start), u)
        if self.phase == "push":
            target = obj.copy()
        elif self.phase == "glide":
            target = np.r_[start, obj[2]]
        elif self.phase == "down":
            target = np.r_[far, obj[2]]
        else:
            target = np.r_[far, obj[2] + self.lift]
        return self._torques(target), self.phase


def _state(data: Any) -> np.ndarray:
    return np.concatenate([data.qpos, data.qvel]).astype(np.float64)


def scripted_episode(
    env: Any, seed: int, steps: int = 100, pusher: ScriptedPusherV5 | None = None
) -> dict[str, Any]:
    """One scripted episode from ``env.reset(seed=seed)`` (``env``: ``gymnasium.make("Pusher-v5")``).

    Returns:
        ``{"observations": (T + 1, 23), "actions": (T, 7) N m, "states": (T + 1, nq + nv)
        [qpos, qvel], "phases": [T str]}``; observation components 17-19 are the object's
        position, m. The episode ends early when the environment ends it.
    """
    check_int("steps", steps)
    pusher = pusher if pusher is not None else ScriptedPusherV5(env)
    pusher.reset()
    obs, _ = env.reset(seed=int(seed))
    observations, states, actions, phases = [np.asarray(obs, np.float64)], [_state(pusher.data)], [], []
    for _ in range(steps):
        a, phase = pusher.act()
        obs, _, terminated, truncated, _ = env.step(a.astype(np.float32))
        observations.append(np.asarray(obs, np.float64))
        states.append(_state(pusher.data))
        actions.append(a)
        phases.append(phase)
        if terminated or truncated:
            break
    return {
        "observations": np.stack(observations),
        "actions": np.stack(actions),
        "states": np.stack(states),
        "phases": phases,
    }
