"""The body's joint dynamics read from its MuJoCo model: ``dq`` and ``v`` as known laws.

With ``ModelConfig.dynamics = "mjcf"`` (which needs ``kinematics = "mjcf"``) the agent does not
learn how its torques move its joints either: ``dq`` and ``v`` come from the body's own MJCF,
stepped by MuJoCo with the contacts of the body and its fixed surroundings only,

    (q, v) = step^k(q_prev, v_prev, act),    dq = q - q_prev,

k the environment's frame skip, the action held over the k substeps (as Gymnasium's
``do_simulation``), the joints outside the spec's at their ``qpos0`` and at rest. The joint
limits, damping, armature, the actuators' gains and the body's contacts with itself and with
static geometry (a table it presses on, a wall) are the MJCF's: a geom collides unless it sits
on a body that moves by joints none of which is the spec's (an object, a goal marker), whose
geoms are switched off (:func:`mobile_geoms`). What is left to learn is how the body moves the
objects. The map is exact while the body touches no object; an object's push back on the body
is not in it (residual sd ``sigma``).

MuJoCo is not differentiable here: the mechanisms refuse inputs that require a gradient, so
plan with the sampling planner (``refine_steps = 0``). The candidates of one planner step are
simulated in one :func:`mujoco.rollout.rollout` call (once for all ensemble members: a fixed
law of inputs the members share runs once, :meth:`models.WorldModel.predict`); ``dq`` and ``v``
share it (the two sites get the same parents, the second reads the first's result).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import gymnasium
import mujoco
import numpy as np
import torch
from mujoco import rollout as mj_rollout
from torch import Tensor

from models import Mechanism
from models.checks import check_float, check_int
from models.mechanisms import Seed
from pal.agent.body_checks import mujoco_model
from pal.agent.spec import EnvSpec

__all__ = ["JointSimulator", "SimulatedJointMechanism", "dynamics_mechanisms", "mjcf_xml", "mobile_geoms"]

_FULL = mujoco.mjtState.mjSTATE_FULLPHYSICS


def mjcf_xml(env: gymnasium.Env) -> str:
    """The MJCF of a MuJoCo env as one XML string (its ``fullpath``, read by MuJoCo).

    Raises:
        ValueError: not a Gymnasium MuJoCo env with a ``fullpath``.
    """
    path = getattr(env.unwrapped, "fullpath", None)
    if mujoco_model(env) is None or path is None:
        raise ValueError(
            f"dynamics='mjcf' needs a Gymnasium MuJoCo env with a model file, got {type(env.unwrapped).__name__}"
        )
    return mujoco.MjSpec.from_file(str(path)).to_xml()


def mobile_geoms(model: mujoco.MjModel, joints: Sequence[int]) -> np.ndarray:
    """Ids of the geoms on bodies moved by some joint, none of which is one of ``joints``.

    A body moves by the joints of its own and of its ancestors up to the world; one moved by no
    joint is static (the world's geometry), one moved by a joint of ``joints`` is the body's.
    """
    body_joints: list[set[int]] = [set() for _ in range(model.nbody)]
    for b in range(1, model.nbody):  # parents come before children in MuJoCo's body order
        own = range(model.body_jntadr[b], model.body_jntadr[b] + model.body_jntnum[b])
        body_joints[b] = body_joints[model.body_parentid[b]] | set(own)
    mine = set(joints)
    moved = [b for b in range(model.nbody) if body_joints[b] and not body_joints[b] & mine]
    return np.flatnonzero(np.isin(model.geom_bodyid, moved))


class JointSimulator:
    """The body of an MJCF, its contacts with objects off, stepped in batches (module docstring).

    Args:
        xml: the MJCF as a string. joints: the spec's joint names, in its order (hinge or slide).
        frame_skip: k, MuJoCo substeps per environment step.

    Shapes: :meth:`step` takes ``(..., nu + 2 n)`` = ``[act, q_prev, v_prev]`` and returns
    ``(q, v)``, each ``(..., n)``.
    """

    def __init__(self, xml: str, joints: Sequence[str], frame_skip: int) -> None:
        try:
            self.model = mujoco.MjModel.from_xml_string(xml)
        except ValueError as exc:
            raise ValueError(f"the MJCF does not compile: {exc}") from exc
        self.xml, self.joints = xml, tuple(joints)
        self.frame_skip = check_int("frame_skip", frame_skip, minimum=1)
        ids = [mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_JOINT, j) for j in self.joints]
        missing = [j for j, i in zip(self.joints, ids, strict=True) if i < 0]
        if missing or not ids:
            raise ValueError(f"joints {missing or list(joints)} are not joints of the MJCF")
        off = mobile_geoms(self.model, ids)
        self.model.geom_contype[off] = 0
        self.model.geom_conaffinity[off] = 0
        self.qpos = np.array([1 + self.model.jnt_qposadr[i] for i in ids])
        self.qvel = np.array([1 + self.model.nq + self.model.jnt_dofadr[i] for i in ids])
        self.data = mujoco.MjData(self.model)
        self.template = np.empty(mujoco.mj_stateSize(self.model, _FULL))
        mujoco.mj_getState(self.model, self.data, self.template, _FULL)
        self.nu, self.n = self.model.nu, len(ids)
        self._cache: tuple[Tensor, Tensor, Tensor] | None = None

    @property
    def in_dim(self) -> int:
        """``nu + 2 n``: the actuators' controls, then the joints' angles and velocities."""
        return self.nu + 2 * self.n

    def step(self, z: Tensor) -> tuple[Tensor, Tensor]:
        """``(q, v)`` after one environment step from ``z = [act, q_prev, v_prev]`` (class docstring)."""
        if z.requires_grad and torch.is_grad_enabled():
            raise ValueError(
                "the MJCF's joint dynamics have no gradient: plan with the sampling planner "
                "(refine_steps=0) and infer actions without gradients through dq and v"
            )
        if z.shape[-1] != self.in_dim:
            raise ValueError(f"joint dynamics input has last dim {z.shape[-1]}, expected {self.in_dim}")
        if self._cache is not None and self._cache[0].shape == z.shape and torch.equal(self._cache[0], z):
            return self._cache[1], self._cache[2]
        flat = z.detach().reshape(-1, self.in_dim).to(torch.float64).numpy()
        act, q_prev, v_prev = np.split(flat, [self.nu, self.nu + self.n], axis=1)
        state = np.repeat(self.template[None], len(flat), axis=0)
        state[:, self.qpos], state[:, self.qvel] = q_prev, v_prev
        control = np.repeat(act[:, None], self.frame_skip, axis=1)
        states, _ = mj_rollout.rollout(self.model, self.data, state, control)
        last = states[:, -1]
        shape = (*z.shape[:-1], self.n)
        q = torch.as_tensor(last[:, self.qpos], dtype=z.dtype).reshape(shape)
        v = torch.as_tensor(last[:, self.qvel], dtype=z.dtype).reshape(shape)
        self._cache = (z.detach().clone(), q, v)
        return q, v


class SimulatedJointMechanism(Mechanism):
    """``dq = q - q_prev`` or ``v`` from the MJCF's joint dynamics (module docstring).

    Args:
        xml, joints, frame_skip: the :class:`JointSimulator`'s (or ``simulator``, shared with
            the other site). output: ``"dq"`` or ``"v"``. sigma: the fixed residual sd (rad, rad/s).

    Shapes: parents ``(..., nu + 2 n)`` = ``[act, q_prev, v_prev]`` -> ``(..., n)``.
    """

    kind = "mjcf_joints"
    serialisable = True
    config_keys = frozenset({"xml", "joints", "frame_skip", "output", "sigma", "in_dim"})

    def __init__(
        self,
        xml: str,
        joints: Sequence[str],
        frame_skip: int,
        output: str,
        sigma: float = 1e-4,
        in_dim: int | None = None,
        simulator: JointSimulator | None = None,
    ) -> None:
        if output not in ("dq", "v"):
            raise ValueError(f"output must be 'dq' or 'v', got {output!r}")
        sim = simulator if simulator is not None else JointSimulator(xml, joints, frame_skip)
        if in_dim is not None and in_dim != sim.in_dim:
            raise ValueError(f"in_dim must be nu + 2 n = {sim.in_dim}, got {in_dim}")
        super().__init__(sim.in_dim, sim.n, check_float("sigma", sigma, minimum=0.0, min_open=True))
        self.simulator, self.output = sim, output

    @property
    def trainable(self) -> bool:
        """False: a known law is given, not learned."""
        return False

    def core(self, z: Tensor) -> Tensor:
        """``dq`` or ``v`` from ``[act, q_prev, v_prev]`` (the normalisers stay the identity)."""
        q, v = self.simulator.step(z)
        if self.output == "v":
            return v
        sim = self.simulator
        return q - z[..., sim.nu : sim.nu + sim.n]

    def config(self) -> dict[str, Any]:
        """JSON-compatible constructor arguments (the MJCF as its XML string)."""
        return {
            "kind": self.kind,
            "in_dim": self.in_dim,
            "xml": self.simulator.xml,
            "joints": list(self.simulator.joints),
            "frame_skip": self.simulator.frame_skip,
            "output": self.output,
            "sigma": float(self.sigma.detach()[0]),
        }

    @classmethod
    def from_config(cls, config: Mapping[str, Any], seed: Seed = 0) -> SimulatedJointMechanism:
        """Build from :meth:`config` output without ``kind``; ``seed`` is unused."""
        return cls(**config)


def dynamics_mechanisms(env: gymnasium.Env, spec: EnvSpec, sigma: float, servo: bool) -> dict[str, Mechanism]:
    """``{"dq", "v"}`` from the env's MJCF, sharing one :class:`JointSimulator` (module docstring).

    Raises:
        ValueError: not a MuJoCo env, a spec without joint velocities (``v`` is a site of the
            dynamics) or with transformed angles (q must be the MJCF's ``qpos``), or servo
            actions (they must be the actuators' controls).
    """
    xml = mjcf_xml(env)
    if spec.velocities is None:
        raise ValueError(
            "dynamics='mjcf' needs a spec with joint velocities (v_prev is a parent of dq and v)"
        )
    if spec.angles.transform is not None:
        raise ValueError("dynamics='mjcf' needs the joint angles as sensed (qpos), not through a transform")
    if servo:
        raise ValueError("dynamics='mjcf' needs torque actions (the actuators' controls), not servo targets")
    sim = JointSimulator(xml, spec.joints, int(getattr(env.unwrapped, "frame_skip", 1)))
    return {
        site: SimulatedJointMechanism(xml, spec.joints, sim.frame_skip, site, sigma, simulator=sim)
        for site in ("dq", "v")
    }
