"""Goals: what the goal mode reaches for (objects, or the effector itself) and the checks on them.

A goal is a target position for an object (``pos.o``) or for the effector (``ee``, its first d
components; a reaching task). It comes from the user (``Agent(goal={name: target})``, names of
:attr:`pal.agent.spec.EnvSpec.goal_names`) or from the goals the spec observes (an object's
``goal`` sensor, ``effector_goal``). A goal mode with nothing to reach is an error, never a
silent hold.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from pal.agent.senses import Percept
from pal.agent.spec import EnvSpec

__all__ = ["check_reachable", "check_targets", "current"]


def check_targets(spec: EnvSpec, targets: Mapping[str, Any]) -> dict[str, np.ndarray]:
    """Name -> finite ``(d,)`` target, m, for objects or the effector.

    Raises:
        ValueError: a name that is neither an object nor the effector, or a target of another
            shape or not finite.
    """
    if not isinstance(targets, Mapping):
        raise ValueError(f"targets must be a mapping name -> position, got {type(targets).__name__}")
    out = {}
    for name, value in targets.items():
        if name not in spec.goal_names:
            raise ValueError(
                f"target names unknown object {name!r}; objects are {list(spec.object_names)}"
                + (
                    f", the effector is {spec.effector_name!r}"
                    if spec.effector is not None
                    else ", and there is no effector"
                )
            )
        d = spec.goal_dim(name)
        v = np.asarray(value, dtype=np.float64)
        if v.shape != (d,) or not np.all(np.isfinite(v)):
            raise ValueError(f"target of {name!r} is {value!r}; expected a finite ({d},) in metres")
        out[name] = v
    return out


def check_reachable(spec: EnvSpec, goal: Mapping[str, np.ndarray]) -> None:
    """Refuse a goal mode with nothing to reach: no user goal and no observed goal.

    Raises:
        ValueError: naming what the spec has and how to give a goal.
    """
    if goal:
        return
    if spec.effector_goal is not None or any(o.goal is not None for o in spec.objects):
        return
    raise ValueError(
        f"the goal mode has nothing to reach: no goal= was given and the spec observes no goal (objects "
        f"{list(spec.object_names)}, effector {spec.effector_name if spec.effector is not None else None!r}); "
        "give Agent(..., goal={name: target}), an ObjectSpec goal sensor, or EnvSpec(effector_goal=...)"
    )


def current(spec: EnvSpec, percept: Percept, estimate: Mapping[str, Any], name: str) -> np.ndarray | None:
    """The current position of ``name``: the object's estimate, or the effector's first d components."""
    if spec.effector is not None and name == spec.effector_name:
        return None if percept.effector is None else percept.effector[: spec.goal_dim(name)]
    return estimate.get(name)
