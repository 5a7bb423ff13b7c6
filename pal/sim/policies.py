"""Motor-babbling policies: i.i.d. uniform commands, or a smoother Ornstein-Uhlenbeck process.

A policy draws blocks of commands, float32 ``(n, n_actuators)``, from its own seeded
``numpy.random.Generator``. Commands are float32 so that the stored ``act`` columns are
exactly what was applied, and a stored transition replays bit for bit. Drawing ``n``
commands and then ``m`` gives the same values as drawing ``n + m`` at once, and
:meth:`get_state`/:meth:`set_state` carry the generator's state as JSON, so a resumed
babbling run continues the same stream.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, Protocol

import numpy as np

__all__ = ["POLICIES", "OUPolicy", "Policy", "UniformPolicy", "make_policy"]

#: Names accepted by :func:`make_policy`.
POLICIES = ("uniform", "ou")


def _check_ranges(low: np.ndarray, high: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    low, high = np.asarray(low, np.float64), np.asarray(high, np.float64)
    if low.shape != high.shape or low.ndim != 1 or low.size == 0:
        raise ValueError(f"low/high must be equal-length 1-d arrays, got shapes {low.shape} and {high.shape}")
    bad = np.flatnonzero(~(np.isfinite(low) & np.isfinite(high) & (low < high)))
    if bad.size:
        raise ValueError(
            f"command ranges {[(float(low[i]), float(high[i])) for i in bad]} at actuator indices {bad.tolist()} "
            "must be finite with low < high; babbling needs ctrllimited actuators"
        )
    return low, high


class Policy(Protocol):
    """What the babbling data source needs from a policy."""

    name: str
    low: np.ndarray  # (n_actuators,) lowest commands
    high: np.ndarray  # (n_actuators,) highest commands

    def sample(self, n: int) -> np.ndarray:
        """The next ``n`` commands, float32 ``(n, n_actuators)``."""
        ...

    def get_state(self) -> dict[str, Any]:
        """JSON-compatible state (generator and process state)."""
        ...

    def set_state(self, state: Mapping[str, Any]) -> None:
        """Restore a state from :meth:`get_state`."""
        ...

    def config(self) -> dict[str, Any]:
        """JSON-compatible parameters, for dataset metadata."""
        ...


class UniformPolicy:
    """i.i.d. uniform commands over each ``[low, high)``, as in the thesis's babbling (§5.2.1).

    Args:
        low, high: (n_actuators,) command bounds (ctrl units).
        rng: the generator to draw from.
    """

    name = "uniform"

    def __init__(self, low: np.ndarray, high: np.ndarray, rng: np.random.Generator) -> None:
        self.low, self.high = _check_ranges(low, high)
        self.rng = rng

    def sample(self, n: int) -> np.ndarray:
        """The next ``n`` i.i.d. uniform commands, float32 ``(n, n_actuators)``."""
        return self.rng.uniform(self.low, self.high, size=(n, self.low.size)).astype(np.float32)

    def get_state(self) -> dict[str, Any]:
        """JSON-compatible state: the generator state."""
        return {"bit_generator": self.rng.bit_generator.state}

    def set_state(self, state: Mapping[str, Any]) -> None:
        """Restore a state from :meth:`get_state`."""
        self.rng.bit_generator.state = dict(state["bit_generator"])

    def config(self) -> dict[str, Any]:
        """JSON-compatible parameters: name and command bounds."""
        return {"name": self.name, "low": self.low.tolist(), "high": self.high.tolist()}


class OUPolicy:
    """Ornstein-Uhlenbeck commands, clipped to ``[low, high]``: smooth, temporally correlated.

    The latent process x (one per actuator) is sampled exactly at the step interval dt:

        x(t+dt) = mu + (x(t) - mu) e^{-theta dt} + s sqrt(1 - e^{-2 theta dt}) eps,  eps ~ N(0, 1)

    with mu the range midpoint and the stationary standard deviation
    ``s = sigma * (high - low) / 2``. The command is ``clip(x, low, high)``. x starts from
    its stationary distribution and is not reset with the environment.

    Args:
        low, high: (n_actuators,) command bounds.
        rng: the generator to draw from.
        dt: time between commands, s (the environment step, 0.25 s for the shipped bodies).
        theta: mean-reversion rate, 1/s (default 1.0: correlation e^{-0.25} = 0.78 between
            0.25 s steps).
        sigma: stationary standard deviation as a fraction of the half-range (default 0.5).
    """

    name = "ou"

    def __init__(
        self,
        low: np.ndarray,
        high: np.ndarray,
        rng: np.random.Generator,
        *,
        dt: float,
        theta: float = 1.0,
        sigma: float = 0.5,
    ) -> None:
        self.low, self.high = _check_ranges(low, high)
        for key, value in (("dt", dt), ("theta", theta), ("sigma", sigma)):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{key} must be a finite number > 0, got {value!r}")
        self.rng, self.dt, self.theta, self.sigma = rng, float(dt), float(theta), float(sigma)
        self.mu = (self.low + self.high) / 2
        self.scale = self.sigma * (self.high - self.low) / 2
        self.decay = math.exp(-self.theta * self.dt)
        self.x = self.mu + self.scale * self.rng.standard_normal(self.low.size)

    def sample(self, n: int) -> np.ndarray:
        """The next ``n`` clipped OU commands, float32 ``(n, n_actuators)``; advances the process."""
        eps = self.rng.standard_normal((n, self.low.size))
        innovation = self.scale * math.sqrt(1.0 - self.decay**2)
        out = np.empty((n, self.low.size))
        x = self.x
        for i in range(n):
            x = self.mu + (x - self.mu) * self.decay + innovation * eps[i]
            out[i] = x
        self.x = x
        return np.clip(out, self.low, self.high).astype(np.float32)

    def get_state(self) -> dict[str, Any]:
        """JSON-compatible state: the generator state and the latent process x."""
        return {"bit_generator": self.rng.bit_generator.state, "x": self.x.tolist()}

    def set_state(self, state: Mapping[str, Any]) -> None:
        """Restore a state from :meth:`get_state`."""
        self.rng.bit_generator.state = dict(state["bit_generator"])
        self.x = np.asarray(state["x"], np.float64)

    def config(self) -> dict[str, Any]:
        """JSON-compatible parameters: name, command bounds, dt, theta and sigma."""
        return {
            "name": self.name,
            "low": self.low.tolist(),
            "high": self.high.tolist(),
            "dt": self.dt,
            "theta": self.theta,
            "sigma": self.sigma,
        }


def make_policy(
    name: str,
    low: np.ndarray,
    high: np.ndarray,
    rng: np.random.Generator,
    *,
    dt: float,
    params: Mapping[str, float] | None = None,
) -> UniformPolicy | OUPolicy:
    """Build a policy by name.

    Args:
        name: ``"uniform"`` or ``"ou"``.
        low: (n_actuators,) lower command bounds (ctrl units).
        high: (n_actuators,) upper command bounds (ctrl units).
        rng: the generator to draw from.
        dt: environment step, s (used by ``"ou"``).
        params: extra parameters (``theta``, ``sigma`` for ``"ou"``; none for ``"uniform"``).
    """
    params = dict(params or {})
    if name == "uniform":
        if params:
            raise ValueError(f"the uniform policy takes no parameters, got {sorted(params)}")
        return UniformPolicy(low, high, rng)
    if name == "ou":
        unknown = sorted(set(params) - {"theta", "sigma"})
        if unknown:
            raise ValueError(f"unknown OU parameter(s) {unknown}; expected theta, sigma")
        return OUPolicy(low, high, rng, dt=dt, **params)
    raise ValueError(f"unknown policy {name!r}; expected one of {POLICIES}")
