"""Abstraction variables of a higher world-model layer (thesis §6.4.1, Eq. 6.2).

    Z_k^(l+1)(t) = h_k( x_{S_k}^(l)(t : t + Δt) )

``S_k`` is the support (names of lower-layer variables), ``Δt`` the window (``window`` samples,
t .. t + window - 1) and ``h_k`` the abstraction mechanism: a callable from the windows of the
support, name -> ``(B, window, d)``, to ``(B, dim)``. It may be a rule-like event predicate
(:class:`ContactOnset`, :class:`Moving`, :class:`Opening`, :class:`ReachCompleted`, or the
signed :class:`Displacement`), a learned temporal encoder or a fitted motor primitive
(:mod:`models.abstraction_learned`). Each abstraction carries the :class:`~models.Variable` it
is in the higher layer's :class:`~models.CausalGraph`, so a :class:`~models.WorldModel` on that
graph answers ``do``, counterfactual, state and action queries on the layer as on any other.
Predicates return 0/1 floats of shape ``(B, 1)``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor

from models.checks import as_float_tensor, check_float, check_int, describe
from models.variables import Variable

__all__ = [
    "Abstraction",
    "ContactOnset",
    "Displacement",
    "Moving",
    "Opening",
    "ReachCompleted",
    "WindowError",
    "abstract",
    "windows",
]

#: ``windows -> (B, dim)``: name -> ``(B, window, d)`` windows of the support.
AbstractionMechanism = Callable[[Mapping[str, Tensor]], Tensor]


class WindowError(ValueError):
    """An abstraction's window is longer than the history it is computed on."""


@dataclass(frozen=True)
class Abstraction:
    """One abstraction variable Z_k = h_k(x_S(t : t + window)) (Eq. 6.2).

    Attributes:
        name: the variable's name in the higher layer (``variable.name``).
        support: names of the lower-layer variables S_k that h_k reads.
        window: Δt, samples per window, >= 1.
        mechanism: h_k, ``{name: (B, window, d)} -> (B, variable.dim)``.
        variable: the typed variable of the higher layer's graph.
    """

    name: str
    support: tuple[str, ...]
    window: int
    mechanism: AbstractionMechanism
    variable: Variable

    def __post_init__(self) -> None:
        if not isinstance(self.variable, Variable):
            raise ValueError(
                f"abstraction {self.name!r}: variable must be a Variable, got {describe(self.variable)}"
            )
        if self.variable.name != self.name:
            raise ValueError(
                f"abstraction {self.name!r} carries variable {self.variable.name!r}; the names must agree"
            )
        support = tuple(self.support) if not isinstance(self.support, str) else (self.support,)
        if not support or not all(isinstance(s, str) and s for s in support):
            raise ValueError(
                f"abstraction {self.name!r}: support must be non-empty variable names, got {self.support!r}"
            )
        object.__setattr__(self, "support", support)
        object.__setattr__(self, "window", check_int(f"abstraction {self.name!r}: window", self.window))
        if not callable(self.mechanism):
            raise ValueError(
                f"abstraction {self.name!r}: mechanism must be callable, got {describe(self.mechanism)}"
            )

    def __call__(self, wins: Mapping[str, Tensor]) -> Tensor:
        """The predicate or value over windows ``{name: (B, W, d)}``: ``(B, dim)``."""
        """h_k on a batch of windows; checks the output is ``(B, dim)`` and finite."""
        batch = next(iter(wins.values())).shape[0]
        z = self.mechanism(wins)
        if not isinstance(z, Tensor) or z.shape != (batch, self.variable.dim):
            shape = tuple(z.shape) if isinstance(z, Tensor) else describe(z)
            raise ValueError(
                f"abstraction {self.name!r}: mechanism returned {shape}, expected ({batch}, {self.variable.dim})"
            )
        if not torch.isfinite(z).all():
            raise ValueError(f"abstraction {self.name!r}: mechanism returned non-finite values")
        return z


def _history(history: Mapping[str, Any], names: Sequence[str]) -> tuple[dict[str, Tensor], int]:
    if not isinstance(history, Mapping):
        raise ValueError(f"history must be a mapping name -> (T, d) array, got {describe(history)}")
    out: dict[str, Tensor] = {}
    length: int | None = None
    for n in names:
        if n not in history:
            raise ValueError(f"history has no variable {n!r}; it has {sorted(history)}")
        x = as_float_tensor(history[n], f"history[{n!r}]", torch.float64)
        if x.ndim == 1:
            x = x[:, None]
        if x.ndim != 2:
            raise ValueError(f"history[{n!r}] has shape {tuple(x.shape)}, expected (T, d)")
        if length is not None and x.shape[0] != length:
            raise ValueError(f"history[{n!r}] has {x.shape[0]} steps, the other variables {length}")
        length = x.shape[0]
        out[n] = x
    return out, int(length or 0)


def windows(
    history: Mapping[str, Any], names: Sequence[str], window: int, stride: int = 1
) -> dict[str, Tensor]:
    """Sliding windows x_S(t : t + window) for t = 0, stride, ..., T - window: name -> ``(B, window, d)``.

    Raises:
        WindowError: ``window`` is longer than the history (naming both lengths).
        ValueError: missing names, arrays that are not ``(T, d)`` or of unequal lengths.
    """
    window = check_int("window", window)
    stride = check_int("stride", stride)
    xs, length = _history(history, names)
    if window > length:
        raise WindowError(f"window of {window} steps is longer than the history of {length} steps")
    return {n: x.unfold(0, window, stride).transpose(1, 2).contiguous() for n, x in xs.items()}


def abstract(
    history: Mapping[str, Any], abstractions: Sequence[Abstraction], stride: int = 1
) -> dict[str, Tensor]:
    """Every abstraction over the sliding windows of a history (Eq. 6.2).

    Args:
        history: lower-layer name -> ``(T, d)`` values (arrays or tensors; ``(T,)`` is ``(T, 1)``).
        abstractions: the Z_k to compute.
        stride: steps between window starts.

    Returns:
        name -> ``(B, dim)`` float64 with ``B = (T - window) // stride + 1``; row b is
        ``h_k(x_S(b * stride : b * stride + window))``.

    Raises:
        WindowError: an abstraction's window is longer than the history.
    """
    out: dict[str, Tensor] = {}
    for a in abstractions:
        if not isinstance(a, Abstraction):
            raise ValueError(f"expected Abstraction instances, got {describe(a)}")
        out[a.name] = a(windows(history, a.support, a.window, stride))
    return out


def _one(wins: Mapping[str, Tensor], name: str) -> Tensor:
    if name not in wins:
        raise ValueError(f"windows have no variable {name!r}; they have {sorted(wins)}")
    return wins[name]


def _flag(mask: Tensor) -> Tensor:
    return mask.to(torch.float64)[:, None]


@dataclass(frozen=True)
class ContactOnset:
    """1 where contact starts in the window: below ``threshold`` at its first sample, at or above it later.

    With ``window=2`` the row t is 1 exactly when contact starts at step t + 1.
    """

    variable: str
    threshold: float = 0.5

    def __call__(self, wins: Mapping[str, Tensor]) -> Tensor:
        """The predicate or value over windows ``{name: (B, W, d)}``: ``(B, dim)``."""
        x = _one(wins, self.variable).amax(-1)  # (B, W): the strongest contact component
        return _flag((x[:, 0] < self.threshold) & (x[:, 1:] >= self.threshold).any(-1))


@dataclass(frozen=True)
class Moving:
    """1 where the mean speed over the window, ||x(t+1) - x(t)|| / dt, exceeds ``speed`` (units/s)."""

    variable: str
    speed: float
    dt: float = 1.0

    def __post_init__(self) -> None:
        check_float("speed", self.speed, minimum=0.0)
        check_float("dt", self.dt, minimum=0.0, min_open=True)

    def __call__(self, wins: Mapping[str, Tensor]) -> Tensor:
        """The predicate or value over windows ``{name: (B, W, d)}``: ``(B, dim)``."""
        x = _one(wins, self.variable)
        if x.shape[1] < 2:
            raise ValueError("moving needs a window of at least 2 samples")
        v = (x[:, 1:] - x[:, :-1]).norm(dim=-1).mean(-1) / self.dt
        return _flag(v > self.speed)


@dataclass(frozen=True)
class Opening:
    """Hand opening: component ``index`` (a gripper width or joint angle) rises by at least ``rise`` and never falls.

    On the pushing arm the elbow's extension (its angle rising towards 0) is the opening movement.
    """

    variable: str
    rise: float
    index: int = 0
    slack: float = 1e-6

    def __call__(self, wins: Mapping[str, Tensor]) -> Tensor:
        """The predicate or value over windows ``{name: (B, W, d)}``: ``(B, dim)``."""
        x = _one(wins, self.variable)[..., self.index]
        steps = x[:, 1:] - x[:, :-1]
        return _flag((x[:, -1] - x[:, 0] >= self.rise) & (steps >= -self.slack).all(-1))


@dataclass(frozen=True)
class ReachCompleted:
    """1 where the effector ends within ``radius`` of the target and its last step is shorter than ``speed``.

    Attributes:
        effector: effector variable (its first ``len(target)`` components are compared).
        target: a variable name of the support, or a fixed ``(d,)`` point.
        radius: distance, effector units. speed: largest last-step displacement.
    """

    effector: str
    target: str | tuple[float, ...]
    radius: float
    speed: float = float("inf")

    def __call__(self, wins: Mapping[str, Tensor]) -> Tensor:
        """The predicate or value over windows ``{name: (B, W, d)}``: ``(B, dim)``."""
        ee = _one(wins, self.effector)
        if isinstance(self.target, str):
            tgt = _one(wins, self.target)[:, -1]
        else:
            tgt = torch.as_tensor(self.target, dtype=ee.dtype).expand(ee.shape[0], -1)
        d = tgt.shape[-1]
        near = (ee[:, -1, :d] - tgt).norm(dim=-1) <= self.radius
        last = (ee[:, -1] - ee[:, -2]).norm(dim=-1) if ee.shape[1] > 1 else torch.zeros(ee.shape[0])
        return _flag(near & (last <= self.speed))


@dataclass(frozen=True)
class Displacement:
    """The signed change over the window, x(t + window - 1) - x(t), of components ``index`` (all: None)."""

    variable: str
    index: tuple[int, ...] | None = None

    def __call__(self, wins: Mapping[str, Tensor]) -> Tensor:
        """The predicate or value over windows ``{name: (B, W, d)}``: ``(B, dim)``."""
        x = _one(wins, self.variable)
        if self.index is not None:
            x = x[..., list(self.index)]
        return x[:, -1] - x[:, 0]
