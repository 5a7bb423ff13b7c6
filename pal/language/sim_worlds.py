"""The simulators as worlds of the query language: plans played from saved states (S = 1).

A :class:`SimWorld` implements the :class:`pal.language.world.World` protocol on a MuJoCo
simulator: for each situation it restores the recorded state vector, executes the plan's actions
step by step and reads, at the start and after every step, the same named variables the agent's
world model has (:mod:`pal.agent.graph`):

- ``q`` (J,) joint angles, rad; ``v`` (J,) joint velocities, rad/s (Pusher-v5 only);
- ``ee`` (E,) the effector (hand, fingertip), m;
- per object o: ``pos.o`` (d,) position, m; ``dpos.o`` its displacement over the last step
  (zero at the start); ``rel.o = ee - [pos.o, 0]`` (E,); ``contact.o`` (1,) the share of the
  step's physics sub-steps in which the arm touched it, or with ``contact="touch"`` 1 when it
  touched it in any of them, else 0 (pushing world; zero at the start);
- ``goal.o`` (d,) the goal of an object, where the simulator has one (Pusher-v5).

MuJoCo is deterministic, so every plan is played once per situation (``S = 1``) whatever the
number of samples asked, and twin plans (counterfactuals) share all of their noise trivially.

- :class:`PushingWorld`: :class:`pal.sim.pushing.PushingEnv`, state vectors from
  :meth:`~pal.sim.env.BabblingEnv.get_state` (restored with ``reset(options={"state": s})``),
  actions the servo targets (2,), rad; positions are the true body centres in the table plane.
- :class:`PusherWorld`: Gymnasium's ``Pusher-v5``, state vectors ``[qpos, qvel]``
  (:func:`pusher_state`), restored on reset data; actions the seven torques.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import mujoco
import numpy as np
import torch

from pal.checks import check_int
from pal.language.world import Outcome, Situations

__all__ = [
    "CONTACTS",
    "PusherWorld",
    "PushingWorld",
    "SimWorld",
    "pusher_situations",
    "pusher_state",
    "pushing_situations",
]


class SimWorld:
    """A deterministic simulator played from saved states (module docstring).

    Subclasses give :meth:`restore` (state vector -> the raw values at the start) and
    :meth:`advance` (one action -> the raw values after the step); raw values are ``q``, ``ee``,
    ``pos.o`` (and ``v``, ``goal.o``, ``contact.o`` where sensed), float64 arrays.

    Args:
        objects: the object slot names (``pos.<o>`` ...).
        action_dim: size of one action.
        state_size: size of one state vector.
        position_dim: components of ``pos.o`` (the table plane: 2; 3-D: 3).
    """

    touch: bool = False

    def __init__(self, objects: Sequence[str], action_dim: int, state_size: int, position_dim: int) -> None:
        self.objects = tuple(objects)
        self.action_dim = int(action_dim)
        self.state_size = int(state_size)
        self.position_dim = int(position_dim)

    # ------------------------------------------------------------------ subclass hooks
    def restore(self, state: np.ndarray) -> dict[str, np.ndarray]:
        """Restore ``state`` and return the raw values at the start."""
        raise NotImplementedError

    def advance(self, action: np.ndarray) -> dict[str, np.ndarray]:
        """Execute one action and return the raw values after the step."""
        raise NotImplementedError

    # ------------------------------------------------------------------ playing
    def _derived(
        self, raw: dict[str, np.ndarray], prev: dict[str, np.ndarray] | None
    ) -> dict[str, np.ndarray]:
        out = dict(raw)
        ee = raw["ee"]
        for o in self.objects:
            pos = raw[f"pos.{o}"]
            out[f"dpos.{o}"] = pos - prev[f"pos.{o}"] if prev is not None else np.zeros_like(pos)
            padded = np.zeros_like(ee)
            k = min(pos.size, ee.size)
            padded[:k] = pos[:k]
            out[f"rel.{o}"] = ee - padded
            if self.touch and prev is None:
                out[f"contact.{o}"] = np.zeros(1)
        return out

    def path(self, state: np.ndarray, actions: np.ndarray) -> dict[str, np.ndarray]:
        """One situation: name -> (T + 1, d) values, index 0 the start (module docstring).

        Args:
            state: (state_size,) float64 state vector.
            actions: (T, A) actions.
        """
        steps = [self._derived(self.restore(state), None)]
        for a in actions:
            steps.append(self._derived(self.advance(a), steps[-1]))
        return {n: np.stack([s[n] for s in steps]) for n in steps[0]}

    def play(
        self,
        situations: Situations,
        plans: Sequence[torch.Tensor],
        samples: int = 1,
        generator: torch.Generator | None = None,
    ) -> list[Outcome]:
        """Play every plan from every situation's state (the World protocol; S = 1).

        Args:
            situations: N situations with ``states`` (N, state_size).
            plans: K plans, each (N, T_k, A).
            samples: ignored (deterministic: one sample).
            generator: ignored (no noise).

        Returns:
            K outcomes, paths name -> (N, 1, T_k + 1, d) float64.

        Raises:
            ValueError: no or malformed states, or a plan of the wrong shape or non-finite.
        """
        del samples, generator
        states = situations.states
        if states is None:
            raise ValueError(
                f"{type(self).__name__} replays simulator states; the situations have none (states=None)"
            )
        states = np.asarray(states, dtype=np.float64)
        if states.ndim != 2 or states.shape[1] != self.state_size or not np.all(np.isfinite(states)):
            raise ValueError(
                f"situation states have shape {states.shape}; expected finite (N, {self.state_size})"
            )
        n = states.shape[0]
        out = []
        for k, plan in enumerate(plans):
            a = torch.as_tensor(plan).detach().cpu().double().numpy()
            if a.ndim != 3 or a.shape[0] != n or a.shape[2] != self.action_dim or not np.all(np.isfinite(a)):
                raise ValueError(
                    f"plan {k} has shape {tuple(a.shape)}; expected finite ({n}, T, {self.action_dim})"
                )
            paths = [self.path(states[i], a[i]) for i in range(n)]
            out.append(
                Outcome(
                    {name: torch.as_tensor(np.stack([p[name] for p in paths]))[:, None] for name in paths[0]}
                )
            )
        return out


#: What :class:`PushingWorld` reports as ``contact.o``: the touched share of the step's physics
#: sub-steps, or the touch as a 0/1 switch (the two contact labels of the agent's world model).
CONTACTS = ("strength", "touch")


class PushingWorld(SimWorld):
    """:class:`pal.sim.pushing.PushingEnv` as a world (module docstring).

    Args:
        env: the pushing world (``camera=False`` is enough and faster); its state is changed.
        contact: ``"strength"`` (``contact.o`` the touched share of the step's sub-steps, in
            [0, 1]) or ``"touch"`` (1 when the arm touched o in any sub-step, else 0): the
            meaning the compared world model gives ``contact.o``, so that ``touch`` grades the
            same quantity in both worlds.

    Raises:
        ValueError: an unknown ``contact``.
    """

    touch = True

    def __init__(self, env: Any, contact: str = "strength") -> None:
        if contact not in CONTACTS:
            raise ValueError(f"contact {contact!r} unknown; expected one of {list(CONTACTS)}")
        self.env = env
        self.contact = contact
        super().__init__(env.objects, 2, env.state_size, 2)

    def _raw(self, obs: np.ndarray, info: dict[str, Any]) -> dict[str, np.ndarray]:
        out = {"q": np.asarray(obs[:2], dtype=np.float64), "ee": np.asarray(info["hand"], dtype=np.float64)}
        for k, o in enumerate(self.objects):
            out[f"pos.{o}"] = np.asarray(info["truth"][o][:2], dtype=np.float64)
            if "touch" in info:
                c = np.asarray(info["touch"][k : k + 1], dtype=np.float64)
                out[f"contact.{o}"] = (c > 0).astype(np.float64) if self.contact == "touch" else c
        return out

    def restore(self, state: np.ndarray) -> dict[str, np.ndarray]:
        """``reset(options={"state": state})``; values without contact (it is zero at the start)."""
        obs, info = self.env.reset(options={"state": state})
        raw = self._raw(obs, info)
        return {k: v for k, v in raw.items() if not k.startswith("contact.")}

    def advance(self, action: np.ndarray) -> dict[str, np.ndarray]:
        """One servo step (``frame_skip`` physics steps)."""
        obs, _, _, _, info = self.env.step(np.asarray(action, dtype=np.float64))
        return self._raw(obs, info)


def pusher_state(env: Any) -> np.ndarray:
    """The state vector of Pusher-v5 (unwrapped): ``[qpos, qvel]`` float64 (nq + nv,)."""
    return np.concatenate([env.data.qpos, env.data.qvel]).astype(np.float64)


class PusherWorld(SimWorld):
    """Gymnasium's ``Pusher-v5`` as a world (module docstring): object ``object`` and its goal.

    Args:
        env: ``gymnasium.make("Pusher-v5")`` (it is unwrapped: no time limit); its state is changed.
    """

    def __init__(self, env: Any) -> None:
        self.env = env.unwrapped
        m = self.env.model
        self._nq, self._nv = int(m.nq), int(m.nv)
        super().__init__(("object",), int(m.nu), self._nq + self._nv, 3)

    @staticmethod
    def _raw(obs: np.ndarray) -> dict[str, np.ndarray]:
        o = np.asarray(obs, dtype=np.float64)
        return {"q": o[0:7], "v": o[7:14], "ee": o[14:17], "pos.object": o[17:20], "goal.object": o[20:23]}

    def restore(self, state: np.ndarray) -> dict[str, np.ndarray]:
        """Reset the physics data, set ``qpos``, ``qvel`` and recompute (no warm start carried)."""
        env = self.env
        mujoco.mj_resetData(env.model, env.data)
        env.set_state(state[: self._nq].copy(), state[self._nq :].copy())
        return self._raw(env._get_obs())

    def advance(self, action: np.ndarray) -> dict[str, np.ndarray]:
        """One Pusher step (``frame_skip`` physics steps with the torques held)."""
        obs, *_ = self.env.step(np.asarray(action, dtype=np.float32))
        return self._raw(obs)


def _near_point(rng: np.random.Generator, centre: np.ndarray, radius: tuple[float, float]) -> np.ndarray:
    r, a = rng.uniform(*radius), rng.uniform(-np.pi, np.pi)
    return centre[:2] + r * np.array([np.cos(a), np.sin(a)])


def pushing_situations(
    env: Any,
    n: int,
    rng: np.random.Generator,
    near_fraction: float = 0.5,
    near_radius: tuple[float, float] = (0.07, 0.14),
    max_tries: int = 50,
    babble: tuple[float, float] | None = None,
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """N start situations of the pushing world: a random arm, the box near or anywhere.

    Each situation: joint angles uniform over their ranges; with probability ``near_fraction``
    the box is put ``near_radius`` m from the hand (random bearing and yaw), otherwise where the
    world's reset spawns it; the ball at its spawn place. The world holds the arm for one step
    (servo targets = the angles) so that everything rests; a draw in which the arm touches an
    object or an object moves more than 1 mm in that step is drawn again.

    With ``babble = (local, reach)`` the situation is the state one babbling step later, drawn
    as the agent babbles (:class:`pal.agent.config.BabbleConfig`): with probability ``local`` servo
    targets within ``reach`` rad of the angles, else uniform over the ranges. The arm is then
    moving (and may be pushing) as it is at the start of the steps a babbling agent learns from,
    whose world model does not sense joint velocities; a settled arm is a start it never saw.

    Args:
        env: a :class:`pal.sim.pushing.PushingEnv` (its state is changed).
        n: situations.
        rng: the draws.
        near_fraction: share of box-near-hand draws, in [0, 1].
        near_radius: (low, high) hand-box centre distance of those draws, m.
        max_tries: draws per situation before giving up.
        babble: ``(local, reach)`` of the babbling step, or None for the settled situation.

    Returns:
        ``(values, states)``: start values ``q`` (N, 2), ``ee`` (N, 3), ``pos.<o>`` (N, 2)
        (true body centres, table plane, m), and the (N, state_size) state vectors.

    Raises:
        ValueError: no settled draw within ``max_tries`` for some situation; a bad ``babble``.
    """
    if babble is not None:
        local, reach = (float(x) for x in babble)
        if not (0.0 <= local <= 1.0 and reach >= 0.0):
            raise ValueError(f"babble must be (local in [0, 1], reach >= 0 rad), got {babble!r}")
    world = PushingWorld(env)
    rows: list[dict[str, np.ndarray]] = []
    states = []
    for i in range(n):
        for _ in range(max_tries):
            q = rng.uniform(env.ctrl_low, env.ctrl_high)
            seed = int(rng.integers(2**31))
            obs, info = env.reset(seed=seed, options={"q": tuple(q)})
            options: dict[str, Any] = {"q": tuple(q)}
            if rng.uniform() < near_fraction and "box" in env.objects:
                x, y = _near_point(rng, np.asarray(info["hand"]), near_radius)
                options["objects"] = {"box": (x, y, rng.uniform(-180.0, 180.0))}
            obs, info = env.reset(seed=seed, options=options)
            before = world._raw(obs, info)
            after = world.advance(q)
            moved = max(np.linalg.norm(after[f"pos.{o}"] - before[f"pos.{o}"]) for o in env.objects)
            touched = max(float(after[f"contact.{o}"][0]) for o in env.objects)
            if moved < 1e-3 and touched == 0.0:
                break
        else:
            raise ValueError(
                f"pushing situation {i}: no settled draw in {max_tries} tries; widen near_radius"
            )
        if babble is not None:
            q = after["q"]
            if rng.uniform() < local:
                target = np.clip(q + rng.uniform(-reach, reach, q.size), env.ctrl_low, env.ctrl_high)
            else:
                target = rng.uniform(env.ctrl_low, env.ctrl_high)
            after = world.advance(target)
        states.append(env.get_state())
        rows.append({k: v for k, v in after.items() if not k.startswith("contact.")})
    values = {k: np.stack([r[k] for r in rows]) for k in rows[0]}
    return values, np.stack(states)


def pusher_situations(
    env: Any,
    n: int,
    rng: np.random.Generator,
    spread: float = 0.3,
    near_fraction: float = 0.5,
    near_radius: tuple[float, float] = (0.03, 0.12),
    babble_steps: int = 0,
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """N start situations of Pusher-v5: a random arm, the object near the fingertip or anywhere.

    Each situation: ``reset(seed)`` (the object where Gymnasium puts it), then

    - ``babble_steps = 0``: the seven joint angles uniform within ``spread`` of each range's
      half-width around its middle, clipped to the range, all velocities zero (at rest);
    - ``babble_steps = K > 0``: k ~ U{0, ..., K - 1} steps of uniform random torques, the
      babbling of :mod:`pal.experiments.closed_loop.pusher` (the arm where babbling takes it, moving);

    then the object is at rest (zero velocity, as ``dpos.object`` = 0 says) and, with probability
    ``near_fraction``, moved under the fingertip, ``near_radius`` m from it in the table plane.

    Args:
        env: ``gymnasium.make("Pusher-v5")`` (its state is changed).
        n: situations.
        rng: the draws.
        spread: share of each joint range drawn, in (0, 1] (``babble_steps = 0``).
        near_fraction: share of object-near-fingertip draws.
        near_radius: (low, high) fingertip-object distance in the table plane, m.
        babble_steps: K, the babbling before the situation (0: an arm at rest).

    Returns:
        ``(values, states)``: start values ``q``, ``v`` (N, 7), ``ee`` (N, 3), ``pos.object``
        (N, 3), ``dpos.object`` (N, 3) zeros, ``goal.object`` (N, 3); states (N, nq + nv).

    Raises:
        ValueError: ``babble_steps`` < 0.
    """
    babble_steps = check_int("babble_steps", babble_steps, 0)
    raw = env.unwrapped
    m = raw.model
    low, high = m.jnt_range[:7, 0], m.jnt_range[:7, 1]
    mid, half = (low + high) / 2, (high - low) / 2
    a_low, a_high = (np.asarray(b, dtype=np.float64) for b in (env.action_space.low, env.action_space.high))
    obj = m.body_jntadr[m.body("object").id]
    world = PusherWorld(env)
    rows, states = [], []
    for _ in range(n):
        env.reset(seed=int(rng.integers(2**31)))
        if babble_steps:
            for _ in range(int(rng.integers(babble_steps))):
                raw.step(rng.uniform(a_low, a_high).astype(np.float32))
            qpos, qvel = raw.data.qpos.copy(), raw.data.qvel.copy()
        else:
            qpos, qvel = raw.data.qpos.copy(), np.zeros(m.nv)
            qpos[:7] = np.clip(mid + spread * half * rng.uniform(-1, 1, 7), low, high)
        qvel[m.jnt_dofadr[obj] + np.arange(2)] = 0.0  # the object at rest: dpos.object = 0
        raw.set_state(qpos, qvel)
        if rng.uniform() < near_fraction:
            obs = raw._get_obs()
            target = _near_point(rng, obs[14:16], near_radius)
            axes = m.jnt_axis[obj + np.arange(2), :2].T  # (2, 2) slide axes
            qpos[-4:-2] += np.linalg.solve(axes, target - obs[17:19])
            raw.set_state(qpos, qvel)
        state = pusher_state(raw)
        states.append(state)
        rows.append(world._derived(world.restore(state), None))
    keep = ("q", "v", "ee", "pos.object", "dpos.object", "goal.object")
    return {k: np.stack([r[k] for r in rows]) for k in keep}, np.stack(states)
