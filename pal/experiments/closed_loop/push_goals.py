"""Seeded push-goal episodes of the pushing world, shared by C2 and the hierarchy comparison.

Each episode puts the box at distance r ~ U(start_radius) from the shoulder, at bearing
heading ± U(bearing_deg), with a random yaw, and its goal d ~ U(distance) away in a direction
within ``cone_deg`` of the tangent (bearing + 90°): a push the arm can make from where it is.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from pal.checks import check_float

__all__ = ["check_geometry", "check_interval", "push_goals"]


def check_interval(name: str, value: tuple[float, float], low: float | None = None) -> tuple[float, float]:
    """``(low, high)`` with both finite floats >= ``low`` and low <= high."""
    if len(value) != 2:
        raise ValueError(f"{name} must be (low, high), got {value!r}")
    a, b = (check_float(name, v, low) for v in value)
    if not a <= b:
        raise ValueError(f"{name} must be (low, high) with low <= high, got {value!r}")
    return a, b


def check_geometry(config: Any) -> None:
    """Check a frozen config's ``bearing_deg`` and set its intervals to checked float pairs.

    ``config`` has the fields ``start_radius``, ``bearing_deg``, ``distance`` and ``cone_deg``
    (module docstring); called from its ``__post_init__``.
    """
    check_float("bearing_deg", config.bearing_deg, 0.0, 180.0)
    object.__setattr__(config, "start_radius", check_interval("start_radius", config.start_radius, 0.0))
    object.__setattr__(config, "distance", check_interval("distance", config.distance, 0.0))
    object.__setattr__(config, "cone_deg", check_interval("cone_deg", config.cone_deg))


def push_goals(
    config: Any, n: int, heading: float, shoulder: np.ndarray, stream: int
) -> list[dict[str, Any]]:
    """N episodes (module docstring), table frame, m; ``heading`` in rad.

    ``config`` gives ``seed`` and the geometry fields of :func:`check_geometry` (degrees). The
    draws use the seed sequence ``[seed, stream]`` and episode k's reset seed ``[seed, stream + 1,
    k]``, so experiments with distinct streams get distinct goals.

    Returns:
        Per episode ``{"box": (x, y, yaw_deg), "goal": (2,) array, "seed": int}``.
    """
    seed = config.seed
    rng = np.random.default_rng(np.random.SeedSequence([seed, stream]))
    out = []
    for k in range(n):
        r = rng.uniform(*config.start_radius)
        b = heading + math.radians(rng.uniform(-config.bearing_deg, config.bearing_deg))
        start = shoulder + r * np.array([math.cos(b), math.sin(b)])
        direction = b + math.pi / 2 + math.radians(rng.uniform(*config.cone_deg))
        goal = start + rng.uniform(*config.distance) * np.array([math.cos(direction), math.sin(direction)])
        out.append(
            {
                "box": (float(start[0]), float(start[1]), float(rng.uniform(-180, 180))),
                "goal": goal,
                "seed": int(np.random.SeedSequence([seed, stream + 1, k]).generate_state(1)[0]),
            }
        )
    return out
