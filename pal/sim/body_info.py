"""What a body offers for babbling: its joints, actuators, ranges and force limits, by name.

:func:`body_info` compiles an MJCF file once and caches the answer by file path, size and
modification time, so configurations can check joint and actuator names when they are built,
before anything babbles. :class:`~pal.sim.env.BabblingEnv` uses the same naming functions.

Names: joints and actuators are called by their MuJoCo names. An unnamed actuator is called
after the joint (or tendon, site, body) it drives when that name is free, else
``actuator<i>`` with ``i`` its MuJoCo index; an unnamed hinge or slide joint is called
``joint<i>``. Gymnasium's reacher, whose two motors have no names, thus has the actuators
``joint0`` and ``joint1``.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from pal.sim.bodies import load_model, source_path
from pal.sim.ranges import babbling_ranges

__all__ = [
    "JOINT_TRANSMISSIONS",
    "SCALAR_JOINTS",
    "BodyInfo",
    "actuator_names",
    "body_info",
    "check_selection",
    "dataset_mismatch",
    "driven_joints",
    "force_limit_ranges",
    "joint_names",
]

#: Joint types a dataset records (one coordinate each): hinge (rad) and slide (m).
SCALAR_JOINTS = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))

_TRN_OBJECT = {
    int(mujoco.mjtTrn.mjTRN_JOINT): mujoco.mjtObj.mjOBJ_JOINT,
    int(mujoco.mjtTrn.mjTRN_JOINTINPARENT): mujoco.mjtObj.mjOBJ_JOINT,
    int(mujoco.mjtTrn.mjTRN_TENDON): mujoco.mjtObj.mjOBJ_TENDON,
    int(mujoco.mjtTrn.mjTRN_SITE): mujoco.mjtObj.mjOBJ_SITE,
    int(mujoco.mjtTrn.mjTRN_SLIDERCRANK): mujoco.mjtObj.mjOBJ_SITE,
    int(mujoco.mjtTrn.mjTRN_BODY): mujoco.mjtObj.mjOBJ_BODY,
}
#: Transmission types that drive one joint directly.
JOINT_TRANSMISSIONS = (int(mujoco.mjtTrn.mjTRN_JOINT), int(mujoco.mjtTrn.mjTRN_JOINTINPARENT))
_STATIC_DYN = (
    int(mujoco.mjtDyn.mjDYN_NONE),
    int(mujoco.mjtDyn.mjDYN_FILTER),
    int(mujoco.mjtDyn.mjDYN_FILTEREXACT),
)


def _unique(candidate: str, fallback: str, taken: set[str]) -> str:
    name = candidate if candidate and candidate not in taken else fallback
    while name in taken:
        name += "_"
    taken.add(name)
    return name


def joint_names(model: mujoco.MjModel) -> list[str]:
    """Every joint's name; an unnamed hinge or slide joint is ``joint<i>``, other unnamed ones ``""``."""
    raw = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, i) or "" for i in range(model.njnt)]
    taken = {n for n in raw if n}
    return [
        n or (_unique("", f"joint{i}", taken) if int(model.jnt_type[i]) in SCALAR_JOINTS else "")
        for i, n in enumerate(raw)
    ]


def actuator_names(model: mujoco.MjModel) -> list[str]:
    """Every actuator's name; an unnamed one is named after what it drives (see the module docstring)."""
    raw = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_ACTUATOR, i) or "" for i in range(model.nu)]
    taken = {n for n in raw if n}
    joints = joint_names(model)
    targets = []
    for i in range(model.nu):
        trn, target = int(model.actuator_trntype[i]), int(model.actuator_trnid[i, 0])
        if trn in JOINT_TRANSMISSIONS:
            targets.append(joints[target])
        elif trn in _TRN_OBJECT and target >= 0:
            targets.append(mujoco.mj_id2name(model, _TRN_OBJECT[trn], target) or "")
        else:
            targets.append("")
    shared = {t for t in targets if t and sum(t == u for u, n in zip(targets, raw, strict=True) if not n) > 1}
    return [
        n or _unique("" if targets[i] in shared else targets[i], f"actuator{i}", taken)
        for i, n in enumerate(raw)
    ]


def driven_joints(model: mujoco.MjModel) -> list[tuple[int, ...]]:
    """Per actuator, the ids of the hinge and slide joints it exerts force on at ``qpos0``.

    A joint transmission drives its joint; tendon, site and body transmissions drive the
    joints with a non-zero moment arm in the model's reference configuration.
    """
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    out = []
    for i in range(model.nu):
        start, count = int(data.moment_rowadr[i]), int(data.moment_rownnz[i])
        dofs = data.moment_colind[start : start + count][data.actuator_moment[start : start + count] != 0]
        jids = {int(model.dof_jntid[d]) for d in dofs}
        if int(model.actuator_trntype[i]) in JOINT_TRANSMISSIONS:
            jids.add(int(model.actuator_trnid[i, 0]))
        out.append(tuple(sorted(j for j in jids if int(model.jnt_type[j]) in SCALAR_JOINTS)))
    return out


def force_limit_ranges(model: mujoco.MjModel) -> list[tuple[float, float] | None]:
    """Per actuator, the commands within which no force limit clamps its output, or None.

    For an actuator with a fixed gain k and no bias (a ``motor``, possibly filtered), the force
    ``k * ctrl`` is clamped to ``forcerange``: commands beyond ``forcerange / k`` change
    nothing. A joint's ``actuatorfrcrange`` clamps the joint torque ``gear * k * ctrl``:
    commands beyond ``actuatorfrcrange / (gear * k)``. The result is intersected with
    ``ctrlrange``; None means no limit binds inside it (or the actuator is not of that kind).
    """
    out: list[tuple[float, float] | None] = []
    for i in range(model.nu):
        k = float(model.actuator_gainprm[i, 0])
        simple = (
            int(model.actuator_gaintype[i]) == int(mujoco.mjtGain.mjGAIN_FIXED)
            and int(model.actuator_biastype[i]) == int(mujoco.mjtBias.mjBIAS_NONE)
            and int(model.actuator_dyntype[i]) in _STATIC_DYN
            and k != 0
        )
        if not simple:
            out.append(None)
            continue
        limited = bool(model.actuator_ctrllimited[i])
        lo, hi = (float(v) for v in model.actuator_ctrlrange[i]) if limited else (-np.inf, np.inf)
        ctrl = (lo, hi)
        bounds = []
        if model.actuator_forcelimited[i]:
            bounds.append(model.actuator_forcerange[i] / k)
        trn, target = int(model.actuator_trntype[i]), int(model.actuator_trnid[i, 0])
        gear = float(model.actuator_gear[i, 0])
        if trn in JOINT_TRANSMISSIONS and model.jnt_actfrclimited[target] and gear != 0:
            bounds.append(model.jnt_actfrcrange[target] / (k * gear))
        for b in bounds:
            b_lo, b_hi = sorted(float(v) for v in b)
            lo, hi = max(lo, b_lo), min(hi, b_hi)
        out.append(None if (lo, hi) == ctrl or not lo < hi else (lo, hi))
    return out


@dataclass(frozen=True)
class BodyInfo:
    """Names and ranges of a body, for checking a babbling choice before it runs.

    Attributes:
        name: the model's name (see :func:`pal.sim.bodies.load_model`).
        path: the MJCF file.
        sha256: SHA-256 of the file's bytes.
        timestep: MuJoCo time step, s.
        joints: selectable joints (hinge and slide), in model order.
        actuators: every actuator, in model order.
        ctrl_ranges: actuator -> ``(low, high)`` ctrl range (infinite when not ctrllimited).
        joint_actuators: actuator -> the joint of its joint transmission (hinge or slide only).
        drives: actuator -> the selectable joints it exerts force on.
        force_limits: actuator -> command range within which no force limit binds, or None.
    """

    name: str
    path: Path
    sha256: str
    timestep: float
    joints: tuple[str, ...]
    actuators: tuple[str, ...]
    ctrl_ranges: dict[str, tuple[float, float]]
    joint_actuators: dict[str, str]
    drives: dict[str, tuple[str, ...]]
    force_limits: dict[str, tuple[float, float] | None]


@lru_cache(maxsize=32)
def _info(path: str, mtime_ns: int, size: int) -> BodyInfo:
    loaded = load_model(path)
    m = loaded.model
    all_joints = joint_names(m)
    scalar = [n for i, n in enumerate(all_joints) if n and int(m.jnt_type[i]) in SCALAR_JOINTS]
    acts = actuator_names(m)
    limited = m.actuator_ctrllimited.astype(bool)
    ranges = {
        a: (float(m.actuator_ctrlrange[i, 0]), float(m.actuator_ctrlrange[i, 1]))
        if limited[i]
        else (-np.inf, np.inf)
        for i, a in enumerate(acts)
    }
    joint_of = {
        a: all_joints[int(m.actuator_trnid[i, 0])]
        for i, a in enumerate(acts)
        if int(m.actuator_trntype[i]) in JOINT_TRANSMISSIONS
        and all_joints[int(m.actuator_trnid[i, 0])] in scalar
    }
    drives = {a: tuple(all_joints[j] for j in js) for a, js in zip(acts, driven_joints(m), strict=True)}
    return BodyInfo(
        name=loaded.name,
        path=loaded.path,
        sha256=loaded.sha256,
        timestep=float(m.opt.timestep),
        joints=tuple(scalar),
        actuators=tuple(acts),
        ctrl_ranges=ranges,
        joint_actuators=joint_of,
        drives=drives,
        force_limits=dict(zip(acts, force_limit_ranges(m), strict=True)),
    )


def body_info(source: str | os.PathLike[str]) -> BodyInfo:
    """The :class:`BodyInfo` of a shipped body name or an MJCF path (cached by path, size and mtime).

    Raises:
        MJCFError: the file is missing or MuJoCo rejects it.
    """
    path = source_path(source)
    if not path.is_file():
        load_model(source)  # raises the MJCFError that names the path
    st = path.stat()
    return _info(str(path.resolve()), st.st_mtime_ns, st.st_size)


def check_selection(
    info: BodyInfo,
    *,
    joint: str | None = None,
    actuators: Sequence[str] | None = None,
    action_ranges: Sequence[tuple[str, float, float]] = (),
) -> tuple[str, ...]:
    """Check a babbling choice against a body before anything runs; returns the babbling actuators.

    Args:
        info: the body.
        joint: a joint that must exist and be driven (joint transmission) by a babbling actuator.
        actuators: the babbling actuators (default every actuator that drives a joint); each
            must exist and drive a hinge or slide joint.
        action_ranges: ``(actuator, low, high)`` overrides (see
            :func:`pal.sim.ranges.babbling_ranges`).

    Raises:
        ValueError: an unknown joint or actuator, an actuator named twice or driving no
            joint, no babbling actuator driving ``joint``, or a bad action range.
    """
    where = f"body {info.name!r} ({info.path})"
    if joint is not None and joint not in info.joints:
        raise ValueError(f"unknown joint {joint!r}; the joints of {where} are {list(info.joints)}")
    if actuators is None:
        acts = tuple(a for a in info.actuators if info.drives[a])
    else:
        acts = tuple(actuators)
        unknown = [a for a in acts if a not in info.actuators]
        if unknown:
            raise ValueError(
                f"unknown actuator(s) {unknown}; the actuators of {where} are {list(info.actuators)}"
            )
        duplicates = sorted({a for a in acts if acts.count(a) > 1})
        if duplicates:
            raise ValueError(f"actuator(s) {duplicates} selected more than once")
        idle = [a for a in acts if not info.drives[a]]
        if idle:
            raise ValueError(f"actuator(s) {idle} of {where} drive no hinge or slide joint")
    if joint is not None and not any(info.joint_actuators.get(a) == joint for a in acts):
        drivers = [a for a, j in info.joint_actuators.items() if j == joint]
        raise ValueError(
            f"no babbling actuator drives joint {joint!r} (actuators {list(acts)}); select one whose "
            f"transmission is this joint (--actuator NAME): {drivers}"
        )
    babbling_ranges(acts, info.ctrl_ranges, action_ranges)
    return acts


def dataset_mismatch(
    meta: Mapping[str, Any],
    info: BodyInfo,
    *,
    root: str | os.PathLike[str],
    actuators: Sequence[str] | None,
    frame_skip: int,
    action_ranges: Sequence[tuple[str, float, float]] | None,
) -> str | None:
    """Why a dataset (its metadata) was not recorded for this body and choice, or None.

    Args:
        meta: the dataset's metadata.
        info: the body the dataset should come from (MJCF file hash).
        root: the dataset directory, for the message.
        actuators: the babbling actuators (default every actuator that drives a joint).
        frame_skip: MuJoCo steps per transition.
        action_ranges: the overrides the babbling should have used, or None not to compare
            the command ranges (e.g. for effective-range babbling).

    Returns:
        A one-line message naming the mismatch (body, actuator set, frame skip or command
        ranges) and the flag that fixes it, or None.
    """
    if meta.get("mjcf_sha256") != info.sha256:
        return (
            f"dataset {root} was recorded from body {meta.get('body')!r} ({meta.get('mjcf_path')}, sha256 "
            f"{str(meta.get('mjcf_sha256'))[:12]}...), not from {info.path} (sha256 {info.sha256[:12]}...); "
            "give its body with --mjcf/--body"
        )
    acts = tuple(a for a in info.actuators if info.drives[a]) if actuators is None else tuple(actuators)
    stored_acts = list(meta.get("actuators", ()))
    if sorted(stored_acts) != sorted(acts):
        return (
            f"dataset {root} babbled the actuators {sorted(stored_acts)}, the experiment babbles "
            f"{sorted(acts)}; give the same --actuator flags"
        )
    if meta.get("frame_skip") != frame_skip:
        return (
            f"dataset {root} was recorded with frame skip {meta.get('frame_skip')}, the experiment uses "
            f"{frame_skip}; pass --frame-skip {meta.get('frame_skip')}"
        )
    if action_ranges is not None:
        wanted = babbling_ranges(acts, info.ctrl_ranges, action_ranges)
        stored = {a: tuple(v) for a, v in meta.get("action_ranges", {}).items()}
        differ = {a: (stored.get(a), r) for a, r in wanted.items() if stored.get(a) != r}
        if differ:
            detail = "; ".join(f"{a}: dataset {s}, experiment {w}" for a, (s, w) in differ.items())
            return f"dataset {root} babbled other command ranges ({detail}); give the same --action-range"
    return None
