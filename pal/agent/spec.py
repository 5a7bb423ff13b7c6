"""What the agent knows about an environment: which observation entries, or which perceived objects, are what.

An :class:`EnvSpec` describes any ``gymnasium.Env`` with a ``Box`` action space in the roles the
world model is built from (:mod:`pal.agent.graph`):

- ``angles`` (J,) joint angles and optionally ``velocities`` (J,), from the observation;
- ``effector`` (E,) the end effector's position, m, from the observation or an ``info`` entry;
- ``objects``: each a named position (d,), m, read from the observation (state-based) or
  perceived by Π in the camera frames that the environment puts in ``info`` (``camera``);
  optionally with the position of its goal, from the observation;
- ``touch`` (O,): the contact sensed with each object, from ``info``;
- the actions: their names and bounds, from the action space (or given here).

Each quantity is read by a :class:`Sensor`: observation indices, or an ``info`` key. A spec is
checked when it is made (overlapping or negative indices, an ``info`` key read by two roles, dims that disagree, missing camera)
and against an environment by :func:`check_env` (indices out of range, an observation space
of another shape, actions without finite bounds). :func:`pushing_spec` and :func:`pusher_spec`
describe :class:`pal.sim.pushing.PushingEnv` and Gymnasium's ``Pusher-v5``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import gymnasium
import numpy as np

from pal.agent.transforms import Transform, absolute_from_relative, angle_from_cos_sin
from pal.checks import check_int

__all__ = [
    "PUSHER_JOINTS",
    "EnvSpec",
    "ObjectSpec",
    "Sensor",
    "check_env",
    "pusher_spec",
    "pushing_spec",
    "reacher_spec",
]

#: Joint names of Gymnasium's Pusher-v5 arm (observation entries 0-6 and 7-13), the MJCF's own.
PUSHER_JOINTS = (
    "r_shoulder_pan_joint",
    "r_shoulder_lift_joint",
    "r_upper_arm_roll_joint",
    "r_elbow_flex_joint",
    "r_forearm_roll_joint",
    "r_wrist_flex_joint",
    "r_wrist_roll_joint",
)


@dataclass(frozen=True)
class Sensor:
    """Where one sensed quantity comes from: observation entries or an ``info`` entry.

    Attributes:
        obs: observation indices (in order), or empty.
        info: an ``info`` key whose value is a ``(dim,)`` array, or None.
        dim: the quantity's size; for ``obs`` it is ``len(obs)``, or the transform's output size
            (0 means that).
        transform: optional :class:`pal.agent.transforms.Transform` of the observation entries
            (angles from cos/sin, absolute from relative, an index map).
    """

    obs: tuple[int, ...] = ()
    info: str | None = None
    dim: int = 0
    transform: Transform | None = None

    def __post_init__(self) -> None:
        obs = tuple(self.obs)
        if bool(obs) == (self.info is not None):
            raise ValueError(
                f"a Sensor reads either observation indices or an info key, got obs={obs}, info={self.info!r}"
            )
        for i in obs:
            check_int("observation index", i, minimum=0)
        if len(set(obs)) != len(obs):
            raise ValueError(f"observation indices {list(obs)} repeat an entry")
        object.__setattr__(self, "obs", tuple(int(i) for i in obs))
        if self.transform is not None and not isinstance(self.transform, Transform):
            raise ValueError(f"transform must be a Transform (pal.agent.transforms), got {self.transform!r}")
        if self.transform is not None and not obs:
            raise ValueError(f"a transform applies to observation entries; info[{self.info!r}] has none")
        if obs:
            size = len(obs) if self.transform is None else self.transform.out_dim(len(obs))
            if self.dim not in (0, size):
                raise ValueError(
                    f"Sensor dim {self.dim} disagrees with its {len(obs)} observation indices (giving {size})"
                )
            object.__setattr__(self, "dim", size)
        else:
            check_int(f"dim of info[{self.info!r}]", self.dim)

    def read(self, observation: np.ndarray, info: Mapping[str, Any], what: str) -> np.ndarray:
        """The quantity, float64 ``(dim,)``.

        Raises:
            ValueError: the info key is missing, or its value has another shape or is not finite.
        """
        if self.obs:
            obs = np.asarray(observation, dtype=np.float64)
            raw = obs[list(self.obs)]
            return raw if self.transform is None else self.transform.apply(raw, obs)
        if self.info not in info:
            raise ValueError(
                f"{what} is read from info[{self.info!r}], but the environment's info has {sorted(info)}"
            )
        value = np.asarray(info[self.info], dtype=np.float64).reshape(-1)
        if value.shape != (self.dim,) or not np.all(np.isfinite(value)):
            raise ValueError(f"{what}: info[{self.info!r}] is {value!r}; expected a finite ({self.dim},)")
        return value

    @property
    def reads(self) -> tuple[int, ...]:
        """Every observation index read: the entries and a transform's reference."""
        return self.obs + (() if self.transform is None else self.transform.to)

    def check_first(self, observation: np.ndarray, what: str) -> None:
        """Check the raw entries of the first observation against the transform (cos^2 + sin^2 = 1)."""
        if self.transform is not None:
            raw = np.asarray(observation, dtype=np.float64)[list(self.obs)]
            self.transform.check_values(raw, what)


@dataclass(frozen=True)
class ObjectSpec:
    """One object the agent models.

    Attributes:
        name: its slot name (world-model variables ``pos.<name>`` ...).
        position: its sensor (state-based), or None: perceived by Π (table-plane x, y).
        goal: optional sensor of its goal position (same dim), m.
    """

    name: str
    position: Sensor | None = None
    goal: Sensor | None = None

    def __post_init__(self) -> None:
        if (
            not isinstance(self.name, str)
            or not self.name
            or "." in self.name
            or self.name != self.name.strip()
        ):
            raise ValueError(
                f"object name {self.name!r} must be a non-empty string without dots or spaces at its ends"
            )
        if self.goal is not None and self.goal.dim != self.dim:
            raise ValueError(
                f"goal of {self.name!r} has dim {self.goal.dim}, expected {self.dim} like its position"
            )

    @property
    def perceived(self) -> bool:
        """True when Π supplies the position."""
        return self.position is None

    @property
    def dim(self) -> int:
        """Size of the position: the sensor's, 2 for a perceived object (table plane)."""
        return 2 if self.position is None else self.position.dim


@dataclass(frozen=True)
class EnvSpec:
    """An environment in the roles of the world model (module docstring).

    Attributes:
        joints: joint names.
        angles: sensor of the joint angles (J,), rad.
        velocities: optional sensor of the joint velocities (J,), rad/s.
        effector: optional sensor of the end effector position (E,), m.
        effector_goal: optional sensor of the effector's goal (d <= E: its first d components),
            m; the goal mode then brings the effector there (a reaching task).
        effector_name: the effector's name in goals and targets (``Agent(goal={name: ...})``).
        effector_body: the MJCF body whose frame origin the effector sensor reads, for the
            known kinematics of ``ModelConfig.kinematics = "mjcf"`` (:mod:`pal.agent.kinematics`).
        effector_points: points fixed in ``effector_body``'s frame, m, that outline the part of
            the body that touches objects (e.g. a claw's ends), for :func:`pal.agent.kinematics.point_chains`.
        objects: the modelled objects.
        touch: optional ``info`` sensor of the contact with each object (O,), in [0, 1].
        actions: action names; default ``joints`` (one per joint).
        action_low, action_high: action bounds; default the action space's.
        observation_dim: the observation size the spec is written for (checked against the env).
        camera: ``info`` key of the RGB-D frame (:class:`pal.frames.RGBDFrame`) for perceived
            objects; the frame's ``info`` also needs ``table_from_camera`` (4, 4) and
            ``self_mask`` (H, W) bool (the agent's own body, from its self-model).
        object_momentum: objects keep moving after a push (their previous displacement is a
            parent of the next one).
    """

    joints: tuple[str, ...]
    angles: Sensor
    velocities: Sensor | None = None
    effector: Sensor | None = None
    objects: tuple[ObjectSpec, ...] = ()
    touch: Sensor | None = None
    actions: tuple[str, ...] = ()
    action_low: tuple[float, ...] | None = None
    action_high: tuple[float, ...] | None = None
    observation_dim: int | None = None
    camera: str | None = None
    object_momentum: bool = False
    effector_goal: Sensor | None = None
    effector_name: str = "effector"
    effector_body: str | None = None
    effector_points: tuple[tuple[float, float, float], ...] = ()

    def __post_init__(self) -> None:
        joints = tuple(self.joints)
        if not joints or len(set(joints)) != len(joints):
            raise ValueError(f"joints {list(joints)} must be distinct names, at least one")
        object.__setattr__(self, "joints", joints)
        object.__setattr__(self, "objects", tuple(self.objects))
        object.__setattr__(self, "actions", tuple(self.actions) or joints)
        names = [o.name for o in self.objects]
        if len(set(names)) != len(names):
            raise ValueError(f"object names {names} repeat")
        self._check_effector_goal(names)
        if self.angles.dim != len(joints):
            raise ValueError(f"angles has dim {self.angles.dim}, expected {len(joints)} (one per joint)")
        if self.velocities is not None and self.velocities.dim != len(joints):
            raise ValueError(
                f"velocities has dim {self.velocities.dim}, expected {len(joints)} (one per joint)"
            )
        if self.touch is not None and (self.touch.info is None or self.touch.dim != len(self.objects)):
            raise ValueError(f"touch must be an info sensor of dim {len(self.objects)} (one per object)")
        if any(o.perceived for o in self.objects):
            if self.camera is None:
                raise ValueError(
                    f"objects {[o.name for o in self.objects if o.perceived]} are perceived; give the info key of the camera frames (camera=...)"
                )
            if self.effector is None:
                raise ValueError(
                    "perceived objects are pushed by the effector; give its sensor (effector=...)"
                )
        if self.objects and self.effector is None:
            raise ValueError("objects are moved by the end effector; give its sensor (effector=...)")
        for o in self.objects:
            if o.position is not None and self.effector is not None and o.dim > self.effector.dim:
                raise ValueError(
                    f"object {o.name!r} has dim {o.dim}, more than the effector's {self.effector.dim}"
                )
        self._check_overlaps()
        if (self.action_low is None) != (self.action_high is None):
            raise ValueError(
                "give both action_low and action_high, or neither (then the action space's are used)"
            )
        if self.action_low is not None:
            low, high = (np.asarray(v, dtype=np.float64) for v in (self.action_low, self.action_high))
            _check_bounds(low, high, self.actions, "the spec")
            object.__setattr__(self, "action_low", tuple(low.tolist()))
            object.__setattr__(self, "action_high", tuple(high.tolist()))
        if self.observation_dim is not None:
            check_int("observation_dim", self.observation_dim)

    def _check_points(self) -> None:
        points = tuple(tuple(float(x) for x in p) for p in self.effector_points)
        if any(len(p) != 3 or not all(np.isfinite(p)) for p in points):
            raise ValueError(
                f"effector_points must be finite (x, y, z) triples, got {list(self.effector_points)}"
            )
        if points and self.effector_body is None:
            raise ValueError("effector_points are placed in effector_body's frame; give effector_body")
        object.__setattr__(self, "effector_points", points)

    def _check_effector_goal(self, names: list[str]) -> None:
        if not isinstance(self.effector_name, str) or not self.effector_name or "." in self.effector_name:
            raise ValueError(f"effector_name {self.effector_name!r} must be a non-empty string without dots")
        if self.effector_name in names:
            raise ValueError(
                f"effector_name {self.effector_name!r} is also an object's name; goals would be ambiguous"
            )
        if self.effector_body is not None and (
            not isinstance(self.effector_body, str) or not self.effector_body
        ):
            raise ValueError(
                f"effector_body must be a non-empty MJCF body name or None, got {self.effector_body!r}"
            )
        self._check_points()
        if self.effector_goal is None:
            return
        if self.effector is None:
            raise ValueError(
                f"effector_goal {self.effector_goal} is given but the spec has no effector; give its sensor (effector=...)"
            )
        if self.effector_goal.dim > self.effector.dim:
            raise ValueError(
                f"effector_goal has dim {self.effector_goal.dim}, more than the effector's {self.effector.dim}"
            )

    @property
    def periodic(self) -> bool:
        """True when the angles come from cos/sin (in (-pi, pi]): a step's ``dq`` is wrapped into [-pi, pi)."""
        t = self.angles.transform
        return t is not None and t.kind == "angle_from_cos_sin"

    @property
    def goal_names(self) -> tuple[str, ...]:
        """Names a goal may be given for: the objects, and the effector when the spec has one."""
        return self.object_names + ((self.effector_name,) if self.effector is not None else ())

    def goal_dim(self, name: str) -> int:
        """Size of a goal of ``name`` (an object's dim; the effector goal's, else the effector's)."""
        if self.effector is not None and name == self.effector_name:
            return self.effector.dim if self.effector_goal is None else self.effector_goal.dim
        return self.object(name).dim

    def sensors(self) -> dict[str, Sensor]:
        """Role -> sensor of every sensed quantity (``"goal.<o>"``, ``"pos.<o>"`` for objects)."""
        out = {"angles": self.angles}
        for role in ("velocities", "effector", "touch"):
            if getattr(self, role) is not None:
                out[role] = getattr(self, role)
        if self.effector_goal is not None:
            out[f"goal.{self.effector_name}"] = self.effector_goal
        for o in self.objects:
            if o.position is not None:
                out[f"pos.{o.name}"] = o.position
            if o.goal is not None:
                out[f"goal.{o.name}"] = o.goal
        return out

    def _check_overlaps(self) -> None:
        """Refuse an observation index or an ``info`` key read by two roles (the camera included)."""
        owner: dict[int, str] = {}
        keys: dict[str, str] = {}
        if self.camera is not None:  # the frame and the two entries that come with it
            keys = dict.fromkeys((self.camera, "table_from_camera", "self_mask"), "camera")
        for role, sensor in self.sensors().items():
            for i in sensor.obs:
                if i in owner:
                    raise ValueError(
                        f"observation index {i} is given to both {owner[i]!r} and {role!r}; roles may not overlap"
                    )
                owner[i] = role
            if sensor.info is not None:
                if sensor.info in keys:
                    raise ValueError(
                        f"info key {sensor.info!r} is read by both {keys[sensor.info]!r} and {role!r}; "
                        "roles may not overlap"
                    )
                keys[sensor.info] = role

    @property
    def object_names(self) -> tuple[str, ...]:
        """The object slot names."""
        return tuple(o.name for o in self.objects)

    @property
    def perceived(self) -> tuple[str, ...]:
        """Names of the objects that Π supplies."""
        return tuple(o.name for o in self.objects if o.perceived)

    def object(self, name: str) -> ObjectSpec:
        """The :class:`ObjectSpec` called ``name``."""
        for o in self.objects:
            if o.name == name:
                return o
        raise ValueError(f"object {name!r} is not in the spec; objects are {list(self.object_names)}")


def _check_bounds(low: np.ndarray, high: np.ndarray, names: tuple[str, ...], where: str) -> None:
    if low.shape != (len(names),) or high.shape != (len(names),):
        raise ValueError(
            f"action bounds of {where} have shapes {low.shape} and {high.shape}, expected ({len(names)},) for actions {list(names)}"
        )
    bad = [
        n
        for n, lo, hi in zip(names, low, high, strict=True)
        if not (np.isfinite(lo) and np.isfinite(hi) and lo < hi)
    ]
    if bad:
        k = names.index(bad[0])
        raise ValueError(
            f"actions {bad} have no finite bounds in {where} (e.g. {bad[0]!r}: [{low[k]}, {high[k]}]); "
            "the planner searches within the bounds: give action_low and action_high in the spec"
        )


def check_env(spec: EnvSpec, env: gymnasium.Env) -> tuple[np.ndarray, np.ndarray]:
    """Check ``env`` against ``spec`` and return the action bounds ``(low (A,), high (A,))``.

    Raises:
        ValueError: a non-Box or not 1-D observation or action space, an observation of another
            size than ``spec.observation_dim``, observation indices out of range, an action
            space of another size than the spec's actions, or actions without finite bounds.
    """
    obs_space, act_space = env.observation_space, env.action_space
    if not isinstance(obs_space, gymnasium.spaces.Box) or len(obs_space.shape) != 1:
        raise ValueError(f"the observation space is {obs_space}; the agent reads a 1-D Box")
    size = obs_space.shape[0]
    if spec.observation_dim is not None and size != spec.observation_dim:
        raise ValueError(
            f"the observation space has shape {obs_space.shape}, but the spec is written for ({spec.observation_dim},)"
        )
    for role, sensor in spec.sensors().items():
        out = [i for i in sensor.reads if i >= size]
        if out:
            raise ValueError(
                f"the spec reads observation index {out[0]} for {role!r}, but the observation has {size} entries"
            )
    if not isinstance(act_space, gymnasium.spaces.Box) or act_space.shape != (len(spec.actions),):
        raise ValueError(
            f"the action space is {act_space}; the spec has {len(spec.actions)} actions {list(spec.actions)}"
        )
    if spec.action_low is not None:
        low, high = np.asarray(spec.action_low), np.asarray(spec.action_high)
    else:
        low, high = (np.asarray(v, dtype=np.float64) for v in (act_space.low, act_space.high))
        _check_bounds(low, high, spec.actions, "the action space")
    return low.astype(np.float64), high.astype(np.float64)


def pushing_spec(objects: tuple[str, ...] = ("box", "ball")) -> EnvSpec:
    """:class:`pal.sim.pushing.PushingEnv` (with ``camera=True``): servo targets, sensed hand and touch, perceived objects.

    Observation ``[q_shoulder, q_elbow, dq/dt ...]``; ``info`` has ``hand`` (3,) m, ``touch``
    (n_objects,) and the camera frame (``rgbd``). With the gated displacement (the default
    ``ModelConfig.displacement``) each object's contact switch is observed from the touch: 1 when any touch was sensed over the step.
    """
    from pal.sim.pushing import JOINTS

    return EnvSpec(
        joints=tuple(JOINTS),
        angles=Sensor(obs=(0, 1)),
        effector=Sensor(info="hand", dim=3),
        objects=tuple(ObjectSpec(o) for o in objects),
        touch=Sensor(info="touch", dim=len(objects)),
        observation_dim=4,
        camera="rgbd",
    )


#: Pusher-v5's claw in the frame of ``tips_arm`` (the wrist-roll link's): the ends of its 20 cm
#: crossbar and the centres of its two fingers (capsules of radius 2 cm). The fingertip sensor reads
#: the bar's centre, and the arm touches the object with these geoms, not at that centre.
PUSHER_CLAW = ((0.0, 0.1, 0.0), (0.0, -0.1, 0.0), (0.05, 0.1, 0.0), (0.05, -0.1, 0.0))


def pusher_spec() -> EnvSpec:
    """Gymnasium's ``Pusher-v5``: seven torque-driven joints, the fingertip, the object and its goal.

    Observation (23,): joint angles 0-6, joint velocities 7-13, fingertip 14-16, object 17-19,
    goal 20-22 (centres of mass, m). The object slides on the table, with momentum; its goal
    lies 4.8 cm lower (the goal marker's centre), so the object-goal distance never falls below
    that. Actions: seven torques in [-2, 2].

    There is no touch sensor: with the gated displacement (the default) the object's contact
    switch ``contact.object`` is labelled from the data for training, 1 when the object moved
    more than its noise floor over the step (``||dpos|| > MOVED_SIGMAS * position_sigma``, 3 mm by
    default; :func:`pal.agent.graph.contact_rule`), and is latent (enumerated) elsewhere.
    """
    return EnvSpec(
        joints=PUSHER_JOINTS,
        angles=Sensor(obs=tuple(range(7))),
        velocities=Sensor(obs=tuple(range(7, 14))),
        effector=Sensor(obs=(14, 15, 16)),
        effector_body="tips_arm",
        effector_points=PUSHER_CLAW,
        objects=(ObjectSpec("object", Sensor(obs=(17, 18, 19)), goal=Sensor(obs=(20, 21, 22))),),
        observation_dim=23,
        object_momentum=True,
    )


def reacher_spec() -> EnvSpec:
    """Gymnasium's ``Reacher-v5``: two torque-driven joints, the fingertip and its goal, no wrapper.

    Observation (10,): ``cos q`` 0-1, ``sin q`` 2-3, the target's x, y 4-5, ``qvel`` 6-7, the
    fingertip minus the target (x, y) 8-9. The angles come from the cos/sin entries
    (:func:`pal.agent.transforms.angle_from_cos_sin`), the fingertip from its position relative
    to the target (:func:`pal.agent.transforms.absolute_from_relative`), and the target is the
    effector's goal. Actions: two torques in [-1, 1] (motor actuators, gear 200).
    """
    return EnvSpec(
        joints=("joint0", "joint1"),
        angles=Sensor(obs=(0, 1, 2, 3), transform=angle_from_cos_sin()),
        velocities=Sensor(obs=(6, 7)),
        effector=Sensor(obs=(8, 9), transform=absolute_from_relative(to=(4, 5))),
        effector_goal=Sensor(obs=(4, 5)),
        effector_name="fingertip",
        effector_body="fingertip",
        observation_dim=10,
    )
