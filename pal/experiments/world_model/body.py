"""The body choice of the world-model experiments: which body babbles, and how.

:class:`BodyChoice`: which body (shipped name or MJCF path) and its name, which joint is
analysed, which actuators babble, over which command ranges, with which frame skip. The
``pal experiment``/``pal bench`` flags ``--body/--mjcf/--name/--joint/--actuator/
--frame-skip/--action-range/--effective-range`` set its fields; names, ranges and the file
are checked when it is built (the MJCF is compiled once per file version).
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from pal.checks import check_int
from pal.sim.babbling import BabbleConfig
from pal.sim.bodies import BODIES, check_name
from pal.sim.body_info import BodyInfo, body_info, check_selection, dataset_mismatch

__all__ = ["DEFAULT_JOINT", "BodyChoice"]

#: The analysed joint when none is named and the body has one called so (both shipped bodies).
DEFAULT_JOINT = "finger"


def _one_name(value: Any, what: str) -> str | None:
    """``None``, a name, or a 1-tuple of a name (``--joint`` is repeatable) -> name or None."""
    if value is None or isinstance(value, str):
        return value
    names = list(value)
    if len(names) != 1 or not isinstance(names[0], str):
        raise ValueError(f"{what} must be one name, got {value!r}; the experiments analyse one joint")
    return names[0]


def _resolve_joint(joints: Sequence[str], joint: str | None) -> str:
    """``joint``, else ``"finger"`` if the body has it, else its only joint."""
    if joint is not None:
        return joint
    if DEFAULT_JOINT in joints:
        return DEFAULT_JOINT
    if len(joints) == 1:
        return joints[0]
    raise ValueError(f"the body has joints {list(joints)}; name the one to analyse (--joint NAME)")


def _action_range(item: Any) -> tuple[str, float, float]:
    if isinstance(item, str) or not isinstance(item, Sequence) or len(item) != 3:
        raise ValueError(f"action_range entry {item!r} is not a (actuator, low, high) triple")
    name, low, high = item
    check_name("action_range actuator", name)
    if any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in (low, high)):
        raise ValueError(f"action_range entry {item!r}: low and high must be numbers")
    return name, float(low), float(high)


@dataclass(frozen=True)
class BodyChoice:
    """The body, the analysed joint and how its actuators babble.

    Attributes:
        body: shipped body, one of ``pal.sim.BODIES`` (``"finger"``, ``"arm"``).
        mjcf: path to any MJCF file; when given it replaces ``body``.
        joint: the analysed joint (default ``"finger"``, or the only joint of the model).
        actuator: the actuators that babble (default all); each must drive a joint. The
            analysed action is the selected actuator whose transmission is ``joint``.
        frame_skip: MuJoCo steps per transition (50: 0.25 s on the shipped bodies).
        action_range: ``(actuator, low, high)`` triples babbled instead of the ctrlrange,
            each inside it.
        name: the body's name in reports, caches and metadata (default the model's own).
        effective_range: babble over the effective ranges a probe run finds
            (:func:`pal.sim.ranges.effective_ranges`).

    Raises:
        ValueError: an unknown body, a missing or malformed file, an unknown joint or
            actuator, an actuator that drives no joint or not the analysed one, a frame skip
            < 1, an action range outside the ctrlrange, or a bad name.
    """

    body: str = "finger"
    mjcf: str | None = None
    joint: str | None = None
    actuator: tuple[str, ...] | None = None
    frame_skip: int = 50
    action_range: tuple[tuple[str, float, float], ...] = ()
    name: str | None = None
    effective_range: bool = False

    def __post_init__(self) -> None:
        if self.mjcf is None and self.body not in BODIES:
            raise ValueError(
                f"unknown body {self.body!r}; expected one of {list(BODIES)}, or give mjcf=PATH (--mjcf)"
            )
        joint = _one_name(self.joint, "joint")
        if joint is not None:
            check_name("joint", joint)
        object.__setattr__(self, "joint", joint)
        if self.actuator is not None:
            names = (self.actuator,) if isinstance(self.actuator, str) else tuple(self.actuator)
            object.__setattr__(self, "actuator", tuple(check_name("actuator", a) for a in names))
        object.__setattr__(self, "frame_skip", check_int("frame_skip", self.frame_skip))
        object.__setattr__(self, "action_range", tuple(_action_range(r) for r in self.action_range))
        if self.name is not None:
            check_name("body name", self.name)
        if not isinstance(self.effective_range, bool):
            raise ValueError(f"effective_range must be true or false, got {self.effective_range!r}")
        check_selection(
            body_info(self.source), joint=self.joint, actuators=self.actuator, action_ranges=self.action_range
        )

    @property
    def source(self) -> str:
        """What :class:`~pal.sim.env.BabblingEnv` loads: the MJCF path or the body name."""
        return self.mjcf if self.mjcf is not None else self.body

    def info(self) -> BodyInfo:
        """The body's names and ranges (:func:`pal.sim.body_info.body_info`, cached)."""
        return body_info(self.source)

    def analysed(self) -> tuple[str, str]:
        """``(joint, actuator)`` analysed: the named joint, else ``"finger"`` or the only joint.

        Raises:
            ValueError: several joints and none named, or no babbling actuator drives the joint.
        """
        info = self.info()
        joint = _resolve_joint(info.joints, self.joint)
        acts = check_selection(info, joint=joint, actuators=self.actuator, action_ranges=self.action_range)
        return joint, next(a for a in acts if info.joint_actuators.get(a) == joint)

    def dataset_mismatch(self, meta: Mapping[str, Any], root: str | os.PathLike[str]) -> str | None:
        """Why the dataset with metadata ``meta`` was not babbled by this choice, or None."""
        ranges = None if self.effective_range else self.action_range
        return dataset_mismatch(
            meta,
            self.info(),
            root=root,
            actuators=self.actuator,
            frame_skip=self.frame_skip,
            action_ranges=ranges,
        )

    def babble_config(self, steps: int, seed: int, **settings: Any) -> BabbleConfig:
        """The :class:`~pal.sim.babbling.BabbleConfig` of this choice (all joints recorded).

        Args:
            steps: transitions.
            seed: master seed.
            settings: other :class:`BabbleConfig` fields (``chunk_size``, ``reset_every``, ...).
        """
        body = {
            "body": self.source,
            "name": self.name,
            "actuators": self.actuator,
            "frame_skip": self.frame_skip,
        }
        ranges = {"action_ranges": self.action_range, "effective_range": self.effective_range}
        return BabbleConfig(steps=steps, seed=seed, **body, **ranges, **settings)
