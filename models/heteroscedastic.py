"""Heteroscedastic mechanisms: the mechanism predicts its own scale (PETS-style heads).

The assignment is ``X = f(pa) + sigma(pa) * eps``, ``eps ~ N(0, I)``, computed in the
mechanism's standardised units (the normalisers that :func:`inference.fit` sets, see
:meth:`models.mechanisms.Mechanism.set_normalization`):

    z = (pa - in_loc) / in_scale,      h = trunk(z)                (shared MLP trunk)
    m = W_m h + b_m,                   s = W_s h + b_s             (loc and log-scale heads)
    s <- hi - softplus(hi - s),        s <- lo + softplus(s - lo)  (soft clamp, Chua et al. 2018)
    f(pa) = out_loc + out_scale * m,   sigma(pa) = out_scale * exp(s)

``s`` is the log of the scale in units of the child's training sd (``out_scale``). It
stays above ``lo`` and below ``lo + softplus(hi - lo)`` (``hi`` plus at most
``log(1 + exp(lo - hi))``, 1.2e-4 for the default bounds). The bounds are per component, start at :data:`LOG_SCALE_BOUNDS` = (-8, 1), i.e.
``sigma`` between 3.4e-4 and 2.7 training sd, and are learned by default: :meth:`penalty`
adds ``BOUND_PENALTY * sum(hi - lo)`` to the training loss (PETS uses 0.01), which pulls the
bounds in to where the data needs them. Learned bounds only move inward: the clamp reads
``max(lo, lo_0)`` and ``min(hi, hi_0)`` of the initial ``(lo_0, hi_0)`` (:meth:`scale_bounds`), so
a component whose residuals are all 0 cannot drag ``lo`` to -inf over repeated warm fits. The
clamp keeps the scale away from 0 and inf, so the NLL stays finite.

A head trained while its loc is still improving over-estimates the scale (the residuals it
saw were larger than the final ones), so :func:`inference.fit` recalibrates it on the
validation rows: ``s <- s + log c``, ``c^2 = mean(z^2)`` per component (:meth:`recalibrate`,
stored in the state as ``log_scale_offset``). Each fit starts from offset 0
(:meth:`reset_recalibration`), so the factor is that of the fit's own training and offsets do
not pile up across warm refits; the offset stays within ``+-`` :data:`OFFSET_LIMIT`.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from models.checks import (
    as_float_tensor,
    check_bool,
    check_choice,
    check_finite_tensor,
    check_float,
    check_hidden,
)
from models.mechanisms import ACTIVATIONS, Mechanism, Seed, _linear, _vector, as_generator

log = logging.getLogger(__name__)

__all__ = [
    "BOUND_PENALTY",
    "LOG_SCALE_BOUNDS",
    "OFFSET_LIMIT",
    "HeteroscedasticMechanism",
    "check_log_scale_bounds",
    "shift_log_scale",
    "soft_clamp",
]

#: Initial soft bounds (lo, hi) of the log-scale s = log(sigma / out_scale).
LOG_SCALE_BOUNDS = (-8.0, 1.0)
#: Largest ``|log c|`` of a recalibration offset (a factor of at most 1e4 either way).
OFFSET_LIMIT = math.log(1e4)
#: Weight of the bound penalty ``sum(hi - lo)`` in the training loss (PETS: 0.01).
BOUND_PENALTY = 0.01


def soft_clamp(s: Tensor, low: Tensor, high: Tensor) -> Tensor:
    """``low + softplus((high - softplus(high - s)) - low)``: s smoothly kept inside (low, high)."""
    s = high - F.softplus(high - s)
    return low + F.softplus(s - low)


def shift_log_scale(offset: Tensor, factor: Any) -> None:
    """Add ``log(factor)`` to the buffer ``offset`` ``(out_dim,)`` in place (a scale multiplied by ``factor``).

    Raises:
        ValueError: ``factor`` is not ``out_dim`` finite values > 0.
    """
    factor = torch.as_tensor(factor, dtype=offset.dtype).reshape(-1)
    if factor.shape != offset.shape or not bool(torch.isfinite(factor).all() and (factor > 0).all()):
        raise ValueError(
            f"recalibration factor must be {offset.numel()} finite values > 0, got {factor.tolist()}"
        )
    with torch.no_grad():
        shifted = offset + factor.log()
        clipped = shifted.abs() > OFFSET_LIMIT
        if bool(clipped.any()):
            log.warning(
                "recalibration offsets %s exceed +-%.2f (a factor of 1e4) and are cut to it",
                shifted[clipped].tolist(),
                OFFSET_LIMIT,
            )
        offset.copy_(shifted.clamp(-OFFSET_LIMIT, OFFSET_LIMIT))


def check_log_scale_bounds(value: Any, name: str = "log_scale_bounds") -> tuple[float, float]:
    """A pair ``(low, high)`` of finite numbers with ``low < high``.

    Raises:
        ValueError: naming the value and the rule.
    """
    if isinstance(value, (str, bytes)) or not isinstance(value, Sequence) or len(value) != 2:
        raise ValueError(
            f"{name} must be a pair (low, high) of log-scales (log of sigma / out_scale) with low < high, "
            f"got {value!r}"
        )
    low = check_float(f"{name}[0]", value[0])
    high = check_float(f"{name}[1]", value[1])
    if not low < high:
        raise ValueError(f"{name} must have low < high, got ({low:g}, {high:g})")
    return low, high


def _matrix(value: Any, what: str, shape: tuple[int, int] | None = None) -> Tensor:
    """A finite 2-d ``(out_dim, in_dim)`` tensor; a scalar is 1 x 1, a vector is 1 x in_dim.

    With ``shape``, a scalar fills the whole matrix.
    """
    t = as_float_tensor(value, what).detach()
    if t.ndim == 0:
        t = t.expand(shape) if shape is not None else t.reshape(1, 1)
    elif t.ndim == 1:
        t = t.reshape(1, -1)
    if t.ndim != 2 or t.numel() == 0 or (shape is not None and tuple(t.shape) != shape):
        expected = shape if shape is not None else "(out_dim, in_dim) with both >= 1"
        raise ValueError(f"{what} has shape {tuple(t.shape)}, expected {expected}")
    check_finite_tensor(what, t)
    return t.clone()


class HeteroscedasticMechanism(Mechanism):
    """``X ~ Normal(f(pa), sigma(pa))`` with loc and log-scale heads on one MLP trunk.

    See the module docstring for the equations and the soft clamp of the log-scale.

    Args:
        in_dim: total dimension of the concatenated parents.
        out_dim: dimension of the child variable.
        hidden: trunk widths (ints >= 1; empty: both heads are affine in z).
        activation: one of ``ACTIVATIONS``.
        log_scale_bounds: initial ``(lo, hi)`` of the log-scale in standardised units,
            ``lo < hi`` (default :data:`LOG_SCALE_BOUNDS`).
        learn_bounds: learn ``lo`` and ``hi`` (with :meth:`penalty`); False keeps them fixed.
        seed: int or ``torch.Generator`` for the initial weights (trunk, loc head, scale
            head, in that order); None draws them from the global torch RNG.

    Attributes:
        log_scale_min, log_scale_max: ``(out_dim,)`` bounds ``lo``, ``hi`` (parameters when
            learned, else buffers).
    """

    kind = "hetero"
    serialisable = True
    config_keys = frozenset({"in_dim", "out_dim", "hidden", "activation", "log_scale_bounds", "learn_bounds"})

    def __init__(
        self,
        in_dim: int,
        out_dim: int = 1,
        hidden: Sequence[int] = (32, 32),
        activation: str = "tanh",
        *,
        log_scale_bounds: Sequence[float] = LOG_SCALE_BOUNDS,
        learn_bounds: bool = True,
        seed: Seed = None,
    ) -> None:
        super().__init__(in_dim, out_dim, sigma=None)
        activation = check_choice("activation", activation, sorted(ACTIVATIONS))
        hidden = check_hidden(hidden)
        low, high = check_log_scale_bounds(log_scale_bounds)
        learn_bounds = check_bool("learn_bounds", learn_bounds)
        generator = as_generator(seed)
        self.hidden = hidden
        self.activation = activation
        self.log_scale_bounds = (low, high)
        self.learn_bounds = learn_bounds
        layers: list[nn.Module] = []
        width = self.in_dim
        for h in hidden:
            layers += [_linear(width, h, generator), ACTIVATIONS[activation]()]
            width = h
        self.trunk = nn.Sequential(*layers)
        self.loc_head = _linear(width, self.out_dim, generator)
        self.log_scale_head = _linear(width, self.out_dim, generator)
        lo = torch.full((self.out_dim,), low)
        hi = torch.full((self.out_dim,), high)
        if learn_bounds:
            self.log_scale_min = nn.Parameter(lo)
            self.log_scale_max = nn.Parameter(hi)
        else:
            self.register_buffer("log_scale_min", lo)
            self.register_buffer("log_scale_max", hi)
        self.register_buffer("log_scale_offset", torch.zeros(self.out_dim))

    def _heads(self, parents: Tensor) -> tuple[Tensor, Tensor]:
        """Standardised ``(m, s)`` (s clamped, plus the recalibration offset), each ``(..., out_dim)``."""
        parents = self.check_input(parents)
        h = self.trunk((parents - self.in_loc) / self.in_scale)
        s = soft_clamp(self.log_scale_head(h), *self.scale_bounds())
        return self.loc_head(h), s + self.log_scale_offset

    def scale_bounds(self) -> tuple[Tensor, Tensor]:
        """The soft clamp's ``(lo, hi)``, each ``(out_dim,)``: the learned bounds kept inside the initial ones."""
        low, high = self.log_scale_bounds
        return self.log_scale_min.clamp_min(low), self.log_scale_max.clamp_max(high)

    def reset_recalibration(self) -> None:
        """Set the recalibration offset back to 0 (a factor of 1); :func:`inference.fit` does it first."""
        with torch.no_grad():
            self.log_scale_offset.zero_()

    def recalibrate(self, factor: Any) -> None:
        """Multiply the predicted scale by ``factor`` ``(out_dim,)`` > 0 (variance scaling).

        ``fit`` sets ``factor^2 = mean(z^2)`` over validation rows, ``z = (x - f(pa)) / sigma(pa)``,
        so that the held-out standardised residuals have unit variance (Levi et al. 2022).
        """
        shift_log_scale(self.log_scale_offset, factor)

    def core(self, z: Tensor) -> Tensor:
        """The standardised loc m(z): ``(..., in_dim) -> (..., out_dim)``."""
        return self.loc_head(self.trunk(z))

    def log_scale(self, parents: Tensor) -> Tensor:
        """The clamped standardised log-scale s(pa) = log(sigma(pa) / out_scale): ``(..., out_dim)``."""
        return self._heads(parents)[1]

    def loc_scale(self, parents: Tensor) -> tuple[Tensor, Tensor]:
        """``(f(pa), sigma(pa))``, each ``(..., out_dim)`` in the child's units."""
        m, s = self._heads(parents)
        return self.out_loc + self.out_scale * m, self.out_scale * s.exp()

    def penalty(self) -> Tensor:
        """``BOUND_PENALTY * sum(hi - lo)`` when the bounds are learned, else 0."""
        if not self.learn_bounds:
            return self.log_scale_max.new_zeros(())
        return BOUND_PENALTY * (self.log_scale_max - self.log_scale_min).sum()

    def config(self) -> dict[str, Any]:
        """JSON-compatible constructor arguments (the initial bounds; learned ones are in the state)."""
        return {
            **super().config(),
            "hidden": list(self.hidden),
            "activation": self.activation,
            "log_scale_bounds": list(self.log_scale_bounds),
            "learn_bounds": self.learn_bounds,
        }

    def input_weights(self) -> tuple[str, ...]:
        """The first trunk layer's weight, or both heads' weights without a trunk."""
        return ("trunk.0.weight",) if self.hidden else ("loc_head.weight", "log_scale_head.weight")

    @classmethod
    def from_coefficients(
        cls,
        weight: Any,
        bias: Any = 0.0,
        log_scale_weight: Any = 0.0,
        log_scale_bias: Any = 0.0,
        log_scale_bounds: Sequence[float] = (-30.0, 30.0),
    ) -> HeteroscedasticMechanism:
        """An exact mechanism ``X = W pa + b + exp(clamp(V pa + c)) * eps`` (no trunk, unit normalisers).

        Args:
            weight: W, ``(out_dim, in_dim)``; a scalar means 1 -> 1, a vector in_dim -> 1.
            bias: b per output component (a scalar fills all).
            log_scale_weight: V, shape of W (a scalar fills it).
            log_scale_bias: c per output component (a scalar fills all).
            log_scale_bounds: fixed ``(lo, hi)`` of the soft clamp; the wide default makes
                the clamp the identity to float precision for ``|V pa + c|`` up to about 20.

        The global RNG is not touched.
        """
        w = _matrix(weight, "weight")
        out_dim, in_dim = w.shape
        v = _matrix(log_scale_weight, "log_scale_weight", (out_dim, in_dim))
        mech = cls(in_dim, out_dim, hidden=(), log_scale_bounds=log_scale_bounds, learn_bounds=False, seed=0)
        with torch.no_grad():
            mech.loc_head.weight.copy_(w)
            mech.loc_head.bias.copy_(_vector(bias, out_dim, "bias", allow_scalar=True))
            mech.log_scale_head.weight.copy_(v)
            mech.log_scale_head.bias.copy_(
                _vector(log_scale_bias, out_dim, "log_scale_bias", allow_scalar=True)
            )
        return mech
