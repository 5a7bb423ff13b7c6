"""What a MuJoCo environment's own model says about a spec: actuator kinds, joint angles and velocities.

When the environment is a MuJoCo env (its ``unwrapped.model`` is a ``mujoco.MjModel``, as in
Gymnasium's MuJoCo tasks and pal's bodies), the agent reads there

- the **actuator kind** of each actuator, from ``gaintype``/``biastype``/``biasprm``: a position
  servo has an affine bias ``-kp q`` (``biasprm[1] != 0``), a velocity servo ``-kv qdot`` only,
  a motor no bias (torque ``= gear * ctrl``). :func:`resolve_servo` makes
  :attr:`pal.agent.config.AgentConfig.servo` default to it and refuses a setting that contradicts
  an actuator;
- the **joint angles and velocities** of the spec's joints, when their names are joints of the
  model: :func:`check_joint_sensors` compares them with what the spec's sensors read on the first
  observation, so cosines read as angles (or a velocity sensor on other entries) fail at once.
"""

from __future__ import annotations

import logging
from typing import Any

import gymnasium
import mujoco
import numpy as np

from pal.agent.spec import EnvSpec

__all__ = ["ANGLE_TOLERANCE", "actuator_kinds", "check_joint_sensors", "mujoco_model", "resolve_servo"]

log = logging.getLogger(__name__)

#: How far (rad, rad/s) a sensed joint angle or velocity may be from MuJoCo's on the first observation.
ANGLE_TOLERANCE = 1e-3


def mujoco_model(env: gymnasium.Env) -> tuple[mujoco.MjModel, Any] | None:
    """``(model, data)`` of a MuJoCo environment, or None for another environment."""
    inner = env.unwrapped
    model, data = getattr(inner, "model", None), getattr(inner, "data", None)
    if isinstance(model, mujoco.MjModel) and isinstance(data, mujoco.MjData):
        return model, data
    return None


def actuator_kinds(model: mujoco.MjModel) -> dict[str, str]:
    """Actuator name -> ``"position"``, ``"velocity"``, ``"motor"`` or ``"other"`` (module docstring)."""
    out = {}
    for i in range(model.nu):
        name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_ACTUATOR, i)
        if not name:
            joint = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, int(model.actuator_trnid[i, 0]))
            name = f"actuator {i} (on joint {joint})"
        gain, bias = int(model.actuator_gaintype[i]), int(model.actuator_biastype[i])
        prm = model.actuator_biasprm[i]
        if gain != int(mujoco.mjtGain.mjGAIN_FIXED):
            kind = "other"
        elif bias == int(mujoco.mjtBias.mjBIAS_NONE):
            kind = "motor"
        elif bias == int(mujoco.mjtBias.mjBIAS_AFFINE) and prm[1] != 0:
            kind = "position"
        elif bias == int(mujoco.mjtBias.mjBIAS_AFFINE) and prm[2] != 0:
            kind = "velocity"
        else:
            kind = "other"
        out[name] = kind
    return out


def resolve_servo(env: gymnasium.Env, servo: bool | None) -> bool:
    """Whether the actions are joint position targets: the setting, checked against the MJCF.

    Args:
        env: the environment.
        servo: the setting (None: read it from the actuators; True for a non-MuJoCo env).

    Raises:
        ValueError: ``servo=True`` with an actuator that is not a position servo, or
            ``servo=False`` with every actuator a position servo; the message names the actuator.
    """
    if servo is not None and not isinstance(servo, bool):
        raise ValueError(f"servo is {servo!r}; expected True, False or None (read from the MJCF)")
    found = mujoco_model(env)
    if found is None or found[0].nu == 0:
        return True if servo is None else servo
    kinds = actuator_kinds(found[0])
    others = {n: k for n, k in kinds.items() if k != "position"}
    if servo is None:
        if others and len(others) < len(kinds):
            log.info(
                "actuators %s are not position servos; babbling and holding treat all as torques", others
            )
        return not others
    if servo and others:
        name, kind = next(iter(others.items()))
        raise ValueError(
            f"servo=True, but actuator {name!r} is a {kind} actuator in the MJCF (gaintype/biastype), not a "
            "position servo; leave AgentConfig.servo None to read it, or set servo=False"
        )
    if not servo and not others:
        name = next(iter(kinds))
        raise ValueError(
            f"servo=False, but actuator {name!r} (and every other) is a position servo in the MJCF; its actions "
            "are joint angles: leave AgentConfig.servo None to read it, or set servo=True"
        )
    return servo


def _addresses(
    model: mujoco.MjModel, joints: tuple[str, ...]
) -> tuple[list[int], list[int], list[bool]] | None:
    qpos, dof, hinge = [], [], []
    for name in joints:
        j = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
        kind = int(model.jnt_type[j]) if j >= 0 else -1
        if kind not in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)):
            return None
        qpos.append(int(model.jnt_qposadr[j]))
        dof.append(int(model.jnt_dofadr[j]))
        hinge.append(kind == int(mujoco.mjtJoint.mjJNT_HINGE))
    return qpos, dof, hinge


def check_joint_sensors(spec: EnvSpec, env: gymnasium.Env, q: np.ndarray, v: np.ndarray | None) -> None:
    """Compare the sensed angles ``q`` (J,) and velocities ``v`` (J,) with MuJoCo's ``qpos``/``qvel``.

    Runs only for a MuJoCo environment whose model has every spec joint as a hinge or slide
    joint; hinge angles are compared modulo 2 pi.

    Raises:
        ValueError: a sensed angle or velocity that differs from MuJoCo's by more than
            :data:`ANGLE_TOLERANCE`, naming the joint and the values.
    """
    found = mujoco_model(env)
    if found is None:
        return
    model, data = found
    addr = _addresses(model, spec.joints)
    if addr is None:
        return
    qpos, dof, hinge = addr
    true_q = np.asarray(data.qpos)[qpos]
    diff = np.asarray(q) - true_q
    diff = np.where(hinge, (diff + np.pi) % (2 * np.pi) - np.pi, diff)
    bad = np.flatnonzero(np.abs(diff) > ANGLE_TOLERANCE)
    if bad.size:
        k = int(bad[0])
        raise ValueError(
            f"angles: the spec reads {q[k]:.4f} for joint {spec.joints[k]!r}, but MuJoCo's qpos is {true_q[k]:.4f} rad; "
            "if the entries are cosines and sines, give Sensor(obs=..., transform=angle_from_cos_sin())"
        )
    if v is None:
        return
    true_v = np.asarray(data.qvel)[dof]
    bad = np.flatnonzero(np.abs(np.asarray(v) - true_v) > ANGLE_TOLERANCE)
    if bad.size:
        k = int(bad[0])
        raise ValueError(
            f"velocities: the spec reads {v[k]:.4f} for joint {spec.joints[k]!r}, but MuJoCo's qvel is "
            f"{true_v[k]:.4f}; check the velocity sensor's observation indices"
        )
