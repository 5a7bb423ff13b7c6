"""The 1€ filter (Casiez et al., 2012): an adaptive low-pass filter, vectorised and timestamp-aware.

For a sample x_k at time t_k with Δt = t_k - t_{k-1}:

    α(f_c) = 1 / (1 + τ / Δt),  τ = 1 / (2π f_c)
    dx_k   = α(d_cutoff) (x_k - x̂_{k-1}) / Δt + (1 - α(d_cutoff)) dx_{k-1}
    f_c    = min_cutoff + β |dx_k|
    x̂_k    = α(f_c) x_k + (1 - α(f_c)) x̂_{k-1}

All components of a vector are filtered independently (elementwise cutoffs), in one numpy
operation. Δt comes from the timestamps, so irregular sampling and dropped frames are handled.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["OneEuroConfig", "OneEuroFilter", "one_euro"]


@dataclass(frozen=True)
class OneEuroConfig:
    """Parameters (the proof of concept's defaults).

    Attributes:
        min_cutoff: minimum cutoff frequency, Hz (> 0).
        beta: speed coefficient (>= 0): larger follows fast motion with less lag.
        d_cutoff: cutoff of the derivative filter, Hz (> 0).
    """

    min_cutoff: float = 1.0
    beta: float = 0.0
    d_cutoff: float = 1.0

    def __post_init__(self) -> None:
        if not self.min_cutoff > 0 or not self.d_cutoff > 0 or not self.beta >= 0:
            raise ValueError(f"1€ filter needs min_cutoff > 0, d_cutoff > 0, beta >= 0; got {self}")


def _alpha(cutoff: np.ndarray | float, dt: float) -> np.ndarray | float:
    tau = 1.0 / (2.0 * math.pi * cutoff)
    return 1.0 / (1.0 + tau / dt)


class OneEuroFilter:
    """Stateful filter of (D,) vectors; call it with each sample and its timestamp (s)."""

    def __init__(self, config: OneEuroConfig | None = None) -> None:
        self.config = config or OneEuroConfig()
        self.reset()

    def reset(self) -> None:
        """Forget the history: the next sample passes through unchanged."""
        self._x: np.ndarray | None = None
        self._dx: np.ndarray | None = None
        self._t: float | None = None

    @property
    def last_time(self) -> float | None:
        """Timestamp of the last sample, s (None before the first)."""
        return self._t

    def __call__(self, x: np.ndarray, t: float) -> np.ndarray:
        """Filter one sample.

        Args:
            x: (D,) finite values.
            t: timestamp, s, strictly after the previous sample's.

        Returns:
            (D,) float64 filtered values.

        Raises:
            ValueError: non-finite input, a shape change, or a non-increasing timestamp.
        """
        x = np.asarray(x, dtype=np.float64).reshape(-1)
        if not np.all(np.isfinite(x)) or not math.isfinite(t):
            raise ValueError("the 1€ filter needs finite samples and timestamps")
        if self._x is None or self._t is None or self._dx is None:
            self._x, self._dx, self._t = x.copy(), np.zeros_like(x), float(t)
            return x.copy()
        if x.shape != self._x.shape:
            raise ValueError(f"sample has shape {x.shape}, expected {self._x.shape} like the first sample")
        dt = float(t) - self._t
        if not dt > 0:
            raise ValueError(
                f"timestamp {t} s does not increase (previous {self._t} s); the 1€ filter needs dt > 0"
            )
        cfg = self.config
        a_d = _alpha(cfg.d_cutoff, dt)
        self._dx = a_d * (x - self._x) / dt + (1.0 - a_d) * self._dx
        a = _alpha(cfg.min_cutoff + cfg.beta * np.abs(self._dx), dt)
        self._x = a * x + (1.0 - a) * self._x
        self._t = float(t)
        return self._x.copy()


def one_euro(values: np.ndarray, timestamps: np.ndarray, config: OneEuroConfig | None = None) -> np.ndarray:
    """Filter a whole sequence.

    Args:
        values: (N, D) samples.
        timestamps: (N,) strictly increasing, s.
        config: filter settings (default: ``OneEuroConfig()``).

    Returns:
        (N, D) float64 filtered samples.
    """
    values = np.asarray(values, dtype=np.float64)
    ts = np.asarray(timestamps, dtype=np.float64)
    if values.ndim != 2 or ts.shape != (values.shape[0],):
        raise ValueError(f"values {values.shape} must be (N, D) and timestamps {ts.shape} (N,)")
    filt = OneEuroFilter(config)
    out = np.empty_like(values)
    for k in range(values.shape[0]):
        out[k] = filt(values[k], float(ts[k]))
    return out
