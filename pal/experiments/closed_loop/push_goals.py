"""Seeded push-goal episodes of the pushing world, shared by C2 and the hierarchy comparison.

Each episode puts the box at distance r ~ U(start_radius) from the shoulder, at bearing
heading ± U(bearing_deg), with a random yaw, and its goal d ~ U(distance) away in a direction
within ``cone_deg`` of the tangent (bearing + 90°): a push the arm can make from where it is.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from pal.checks import check_float

__all__ = ["GoalGeometry", "check_interval", "push_goals"]


def check_interval(name: str, value: tuple[float, float], low: float | None = None) -> tuple[float, float]:
    """``(low, high)`` with both finite floats >= ``low`` and low <= high."""
    if len(value) != 2:
        raise ValueError(f"{name} must be (low, high), got {value!r}")
    a, b = (check_float(name, v, low) for v in value)
    if not a <= b:
        raise ValueError(f"{name} must be (low, high) with low <= high, got {value!r}")
    return a, b


@dataclass(frozen=True)
class GoalGeometry:
    """Where the box starts and where its goal lies (module docstring); one setting each.

    Attributes:
        start_radius: ``(low, high)`` distance of the box from the shoulder, m.
        bearing_deg: the box's bearing within ± this of the arm's heading, deg in [0, 180].
        distance: ``(low, high)`` distance of the goal from the box, m.
        cone_deg: ``(low, high)`` direction of the goal from the tangent (bearing + 90°), deg.
    """

    start_radius: tuple[float, float] = (0.16, 0.20)
    bearing_deg: float = 25.0
    distance: tuple[float, float] = (0.04, 0.08)
    cone_deg: tuple[float, float] = (-60.0, 15.0)

    def __post_init__(self) -> None:
        check_float("bearing_deg", self.bearing_deg, 0.0, 180.0)
        object.__setattr__(self, "start_radius", check_interval("start_radius", self.start_radius, 0.0))
        object.__setattr__(self, "distance", check_interval("distance", self.distance, 0.0))
        object.__setattr__(self, "cone_deg", check_interval("cone_deg", self.cone_deg))


def push_goals(
    geometry: GoalGeometry, seed: int, n: int, heading: float, shoulder: np.ndarray, stream: int
) -> list[dict[str, Any]]:
    """N episodes (module docstring), table frame, m; ``heading`` in rad.

    The draws use the seed sequence ``[seed, stream]`` and episode k's reset seed ``[seed, stream + 1,
    k]``, so experiments with distinct streams get distinct goals.

    Returns:
        Per episode ``{"box": (x, y, yaw_deg), "goal": (2,) array, "seed": int}``.
    """
    rng = np.random.default_rng(np.random.SeedSequence([seed, stream]))
    out = []
    for k in range(n):
        r = rng.uniform(*geometry.start_radius)
        b = heading + math.radians(rng.uniform(-geometry.bearing_deg, geometry.bearing_deg))
        start = shoulder + r * np.array([math.cos(b), math.sin(b)])
        direction = b + math.pi / 2 + math.radians(rng.uniform(*geometry.cone_deg))
        goal = start + rng.uniform(*geometry.distance) * np.array([math.cos(direction), math.sin(direction)])
        out.append(
            {
                "box": (float(start[0]), float(start[1]), float(rng.uniform(-180, 180))),
                "goal": goal,
                "seed": int(np.random.SeedSequence([seed, stream + 1, k]).generate_state(1)[0]),
            }
        )
    return out
