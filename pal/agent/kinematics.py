"""The body's kinematics read from a MuJoCo model: ``dee`` and the joint limits as known laws.

With ``ModelConfig.kinematics = "mjcf"`` the agent does not learn how the joints move the
effector (``q_prev, dq -> dee``); it reads the kinematic chain from the body's own MJCF, from
the world to :attr:`pal.agent.spec.EnvSpec.effector_body`, and uses
:class:`models.KinematicMechanism` (``dee = x(clip(q_prev + dq)) - x(clip(q_prev))``, the joint
angles held inside the MJCF's limits), and holds the joint angles themselves at those limits,
``q = clip(q_prev + dq)`` (:class:`models.JointLimitMechanism`). What is still learned is how the torques move the
joints (``dq``, ``v``) and the objects. Every joint on the path must be a hinge among the
spec's joints.

:func:`check_effector` compares the chain's ``x(q)`` with the effector sensor on the first
observation, so a wrong body name fails at once, naming the distance.
"""

from __future__ import annotations

from collections.abc import Sequence

import gymnasium
import mujoco
import numpy as np
import torch

from models import (
    JointLimitMechanism,
    KinematicChain,
    KinematicMechanism,
    KinematicPointsMechanism,
    Mechanism,
)
from pal.agent.body_checks import mujoco_model
from pal.agent.spec import EnvSpec

__all__ = [
    "EFFECTOR_TOLERANCE",
    "check_effector",
    "known_mechanisms",
    "mjcf_chain",
    "point_chains",
    "point_mechanisms",
]

#: How far (in the effector's units, m) the chain's end point may be from the sensed effector on
#: the first observation. Gymnasium's MuJoCo tasks read body positions computed at the start of
#: the last substep (Pusher-v5: about 3 mm behind at rest and while moving slowly).
EFFECTOR_TOLERANCE = 0.02


def _body_path(model: mujoco.MjModel, body: str) -> list[int]:
    """Body ids from the world's first child down to ``body``."""
    bid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, body)
    if bid < 0:
        names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, i) for i in range(1, model.nbody)]
        raise ValueError(f"effector_body {body!r} is not a body of the MJCF; its bodies: {names}")
    path = []
    while bid > 0:
        path.append(bid)
        bid = int(model.body_parentid[bid])
    return path[::-1]


def mjcf_chain(
    model: mujoco.MjModel, joints: Sequence[str], body: str, offset: Sequence[float] = (0.0, 0.0, 0.0)
) -> tuple[KinematicChain, list[int]]:
    """The chain from the world to the point ``offset`` (m) in ``body``'s frame (default its origin), and each hinge's index in ``joints``.

    Raises:
        ValueError: an unknown body, a joint on the path that is not a hinge or not among
            ``joints``, or no hinge on the path.
    """
    rotations, translations, anchors, axes, refs, limits, columns = [], [], [], [], [], [], []
    rot, pos = np.eye(3), np.zeros(3)  # the fixed transform pending since the last hinge
    for bid in _body_path(model, body):
        body_rot = np.empty(9)
        mujoco.mju_quat2Mat(body_rot, model.body_quat[bid])
        rot, pos = rot @ body_rot.reshape(3, 3), pos + rot @ model.body_pos[bid]
        for jid in range(model.body_jntadr[bid], model.body_jntadr[bid] + model.body_jntnum[bid]):
            name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, jid)
            if model.jnt_type[jid] != mujoco.mjtJoint.mjJNT_HINGE:
                raise ValueError(
                    f"joint {name!r} on the path to {body!r} is not a hinge; the chain takes hinges only"
                )
            if name not in joints:
                raise ValueError(
                    f"joint {name!r} on the path to {body!r} is not among the spec's joints {list(joints)}"
                )
            rotations.append(rot)
            translations.append(pos)
            anchors.append(model.jnt_pos[jid].copy())
            axes.append(model.jnt_axis[jid].copy())
            refs.append(float(model.qpos0[model.jnt_qposadr[jid]]))
            low, high = model.jnt_range[jid] if model.jnt_limited[jid] else (-np.inf, np.inf)
            limits.append((low, high))
            columns.append(list(joints).index(name))
            rot, pos = np.eye(3), np.zeros(3)
    if not columns:
        raise ValueError(f"no hinge joint on the path from the world to {body!r}; nothing moves it")
    end = pos + rot @ np.asarray(offset, dtype=np.float64)
    chain = KinematicChain(
        np.stack(rotations), np.stack(translations), np.stack(anchors), np.stack(axes), refs, end, limits
    )
    return chain, columns


def point_chains(env: gymnasium.Env, spec: EnvSpec) -> tuple[list[KinematicChain], list[int]]:
    """One chain per :attr:`EnvSpec.effector_points` point (from the env's MJCF) and the hinges' columns in q.

    Raises:
        ValueError: ``env`` is not a MuJoCo env, or the spec has no points (or a chain cannot be read).
    """
    found = mujoco_model(env)
    if found is None:
        raise ValueError(
            f"effector points need a MuJoCo env (with unwrapped.model), got {type(env.unwrapped).__name__}"
        )
    if not spec.effector_points or spec.effector_body is None:
        raise ValueError("the spec has no effector_points (points in effector_body's frame)")
    pairs = [mjcf_chain(found[0], spec.joints, spec.effector_body, p) for p in spec.effector_points]
    return [c for c, _ in pairs], pairs[0][1]


def point_mechanisms(env: gymnasium.Env, spec: EnvSpec, sigma: float) -> dict[str, Mechanism]:
    """``{"pts_prev": ..., "pts": ...}``: the spec's effector points from ``q_prev`` and ``q`` (:func:`point_chains`)."""
    chains, columns = point_chains(env, spec)
    make = lambda: KinematicPointsMechanism(chains, columns, len(spec.joints), sigma=sigma)  # noqa: E731
    return {"pts_prev": make(), "pts": make()}


def _joint_limits(model: mujoco.MjModel, joints: Sequence[str]) -> list[tuple[float, float]]:
    """Each named joint's ``(low, high)`` (infinite when unlimited); a name the MJCF lacks is refused."""
    out = []
    for name in joints:
        jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
        if jid < 0:
            names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, i) for i in range(model.njnt)]
            raise ValueError(f"joint {name!r} of the spec is not a joint of the MJCF; its joints: {names}")
        limited = bool(model.jnt_limited[jid])
        out.append(tuple(float(v) for v in model.jnt_range[jid]) if limited else (-np.inf, np.inf))
    return out


def known_mechanisms(env: gymnasium.Env, spec: EnvSpec, sigma: float) -> dict[str, Mechanism]:
    """``{"q": JointLimitMechanism, "dee": KinematicMechanism}`` for a MuJoCo env (module docstring).

    Raises:
        ValueError: ``env`` is not a MuJoCo env, a spec joint that is not an MJCF joint, a spec
            with no effector or no ``effector_body``, or a chain that cannot be read (:func:`mjcf_chain`).
    """
    found = mujoco_model(env)
    if found is None:
        raise ValueError(
            f"kinematics='mjcf' needs a MuJoCo env (with unwrapped.model), got {type(env.unwrapped).__name__}"
        )
    out: dict[str, Mechanism] = {"q": JointLimitMechanism(_joint_limits(found[0], spec.joints), sigma=sigma)}
    if spec.effector is None or spec.effector_body is None:
        raise ValueError(
            "kinematics='mjcf' needs a spec with an effector and its effector_body (the MJCF body it reads)"
        )
    chain, columns = mjcf_chain(found[0], spec.joints, spec.effector_body)
    out["dee"] = KinematicMechanism(chain, columns, len(spec.joints), out_dim=spec.effector.dim, sigma=sigma)
    return out


def check_effector(mechanism: KinematicMechanism, q: np.ndarray, effector: np.ndarray, body: str) -> None:
    """The chain's end point at the angles ``q`` ``(n,)`` against the sensed ``effector`` ``(d,)``.

    Raises:
        ValueError: farther apart than :data:`EFFECTOR_TOLERANCE`, naming both and the body.
    """
    cols = list(mechanism.columns)
    with torch.no_grad():
        x = mechanism.chain(torch.as_tensor(np.asarray(q, dtype=np.float64)[cols]))[
            : mechanism.out_dim
        ].numpy()
    gap = float(np.linalg.norm(x - np.asarray(effector, dtype=np.float64)))
    if gap > EFFECTOR_TOLERANCE:
        raise ValueError(
            f"the MJCF chain to {body!r} puts the effector at {x.round(4).tolist()}, {gap:.3f} from the sensed "
            f"{np.round(effector, 4).tolist()} (tolerance {EFFECTOR_TOLERANCE}); check effector_body"
        )
