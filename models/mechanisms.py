"""Local structural mechanisms f_i and their noise scales sigma_i (thesis Eq. 4.31, 5.3-5.4).

Every mechanism defines the additive Gaussian assignment

    X_i = f_i(pa_i) + sigma_i * eps_i,   eps_i ~ N(0, I),

with ``f_i(z) = out_loc + out_scale * g((z - in_loc) / in_scale)``. The affine
normalisers are buffers that :func:`inference.fit` sets from data; ``g`` is the learned
core (MLP or linear), and ``sigma_i = exp(log_sigma)`` is learned per component.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any, ClassVar

import torch
from torch import Tensor, nn

__all__ = [
    "ACTIVATIONS",
    "FunctionMechanism",
    "LinearMechanism",
    "MLPMechanism",
    "Mechanism",
    "make_mechanism",
]

ACTIVATIONS: dict[str, type[nn.Module]] = {
    "tanh": nn.Tanh,
    "relu": nn.ReLU,
    "elu": nn.ELU,
    "silu": nn.SiLU,
    "softplus": nn.Softplus,
}


def _vector(value: Any, n: int, what: str, allow_scalar: bool = False) -> Tensor:
    """A finite ``(n,)`` tensor; a 0-d ``value`` fills all n entries only if ``allow_scalar``."""
    t = torch.as_tensor(value, dtype=torch.get_default_dtype())
    if t.ndim == 0 and allow_scalar:
        t = t.expand(n)
    t = t.reshape(-1)
    if t.numel() != n:
        raise ValueError(f"{what} has {t.numel()} entries, expected {n}")
    if not torch.isfinite(t).all():
        raise ValueError(f"{what} contains NaN or inf: {t.tolist()}")
    return t.clone()


class Mechanism(nn.Module):
    """Base class: a parent-conditioned predictor with a learned residual scale.

    Args:
        in_dim: total dimension of the concatenated parents.
        out_dim: dimension of the child variable.
        sigma: initial residual standard deviation, > 0.

    Shapes:
        ``forward``: ``(..., in_dim) -> (..., out_dim)``; ``sigma``: ``(out_dim,)``.
    """

    kind: ClassVar[str] = ""

    def __init__(self, in_dim: int, out_dim: int, sigma: float = 1.0) -> None:
        super().__init__()
        if in_dim < 1 or out_dim < 1:
            raise ValueError(f"mechanism dims must be >= 1, got in_dim={in_dim}, out_dim={out_dim}")
        if not sigma > 0:
            raise ValueError(f"sigma must be > 0, got {sigma}")
        self.in_dim = int(in_dim)
        self.out_dim = int(out_dim)
        self.register_buffer("in_loc", torch.zeros(in_dim))
        self.register_buffer("in_scale", torch.ones(in_dim))
        self.register_buffer("out_loc", torch.zeros(out_dim))
        self.register_buffer("out_scale", torch.ones(out_dim))
        self.log_sigma = nn.Parameter(torch.full((out_dim,), math.log(sigma)))

    def core(self, z: Tensor) -> Tensor:  # pragma: no cover - abstract
        raise NotImplementedError

    def forward(self, parents: Tensor) -> Tensor:
        if parents.shape[-1] != self.in_dim:
            raise ValueError(
                f"mechanism input has last dim {parents.shape[-1]}, expected {self.in_dim} "
                "(concatenated parent dims)"
            )
        z = (parents - self.in_loc) / self.in_scale
        return self.out_loc + self.out_scale * self.core(z)

    @property
    def sigma(self) -> Tensor:
        """Residual standard deviation sigma_i, shape ``(out_dim,)``."""
        return self.log_sigma.exp()

    def set_sigma(self, sigma: Any) -> None:
        """Set sigma_i: one value per component (a scalar sets all components)."""
        s = _vector(sigma, self.out_dim, "sigma", allow_scalar=True)
        if not (s > 0).all():
            raise ValueError(f"sigma must be > 0, got {s.tolist()}")
        with torch.no_grad():
            self.log_sigma.copy_(s.log())

    def set_normalization(self, in_loc: Any, in_scale: Any, out_loc: Any, out_scale: Any) -> None:
        """Set the affine input/output normalisers (scales must be > 0)."""
        values = {
            "in_loc": _vector(in_loc, self.in_dim, "in_loc"),
            "in_scale": _vector(in_scale, self.in_dim, "in_scale"),
            "out_loc": _vector(out_loc, self.out_dim, "out_loc"),
            "out_scale": _vector(out_scale, self.out_dim, "out_scale"),
        }
        for key in ("in_scale", "out_scale"):
            if not (values[key] > 0).all():
                raise ValueError(f"{key} must be > 0, got {values[key].tolist()}")
        for key, value in values.items():
            getattr(self, key).copy_(value)

    def config(self) -> dict[str, Any]:
        """JSON-compatible constructor arguments; used by :mod:`models.io`."""
        return {"kind": self.kind, "in_dim": self.in_dim, "out_dim": self.out_dim}


class MLPMechanism(Mechanism):
    """f_i as a multilayer perceptron; default 2 hidden layers of 32 tanh units (§5.2.1).

    Args:
        in_dim, out_dim, sigma: see :class:`Mechanism`.
        hidden: hidden layer widths.
        activation: one of ``ACTIVATIONS``.
    """

    kind = "mlp"

    def __init__(
        self,
        in_dim: int,
        out_dim: int = 1,
        hidden: Sequence[int] = (32, 32),
        activation: str = "tanh",
        sigma: float = 1.0,
    ) -> None:
        super().__init__(in_dim, out_dim, sigma)
        if activation not in ACTIVATIONS:
            raise ValueError(f"activation {activation!r} unknown; expected one of {sorted(ACTIVATIONS)}")
        hidden = tuple(int(h) for h in hidden)
        if any(h < 1 for h in hidden):
            raise ValueError(f"hidden sizes must be >= 1, got {hidden}")
        self.hidden = hidden
        self.activation = activation
        layers: list[nn.Module] = []
        width = in_dim
        for h in hidden:
            layers += [nn.Linear(width, h), ACTIVATIONS[activation]()]
            width = h
        layers.append(nn.Linear(width, out_dim))
        self.net = nn.Sequential(*layers)

    def core(self, z: Tensor) -> Tensor:
        return self.net(z)

    def config(self) -> dict[str, Any]:
        return {**super().config(), "hidden": list(self.hidden), "activation": self.activation}


class LinearMechanism(Mechanism):
    """f_i(pa) = W pa + b.

    Use :meth:`from_coefficients` to set a known linear SCM exactly.
    """

    kind = "linear"

    def __init__(self, in_dim: int, out_dim: int = 1, sigma: float = 1.0) -> None:
        super().__init__(in_dim, out_dim, sigma)
        self.linear = nn.Linear(in_dim, out_dim)

    def core(self, z: Tensor) -> Tensor:
        return self.linear(z)

    @classmethod
    def from_coefficients(cls, weight: Any, bias: Any = 0.0, sigma: Any = 1.0) -> LinearMechanism:
        """Exact linear mechanism ``W pa + b``.

        ``weight`` has shape (out_dim, in_dim); a scalar means 1 -> 1 and a vector means
        in_dim -> 1. ``bias`` and ``sigma`` are per output component (a scalar fills all).
        """
        w = torch.as_tensor(weight, dtype=torch.get_default_dtype())
        if w.ndim == 0:
            w = w.reshape(1, 1)
        elif w.ndim == 1:
            w = w.reshape(1, -1)
        if w.ndim != 2:
            raise ValueError(f"weight has shape {tuple(w.shape)}, expected (out_dim, in_dim)")
        mech = cls(w.shape[1], w.shape[0])
        with torch.no_grad():
            mech.linear.weight.copy_(w)
            mech.linear.bias.copy_(_vector(bias, w.shape[0], "bias", allow_scalar=True))
        mech.set_sigma(_vector(sigma, w.shape[0], "sigma", allow_scalar=True))
        return mech


class FunctionMechanism(Mechanism):
    """f_i given as a fixed differentiable torch function (e.g. a known physics law).

    Args:
        fn: ``(..., in_dim) -> (..., out_dim)`` torch function.
        in_dim, out_dim, sigma: see :class:`Mechanism`.

    Not serialisable: :func:`models.io.save` refuses models that contain one.
    """

    kind = "function"

    def __init__(
        self, fn: Callable[[Tensor], Tensor], in_dim: int, out_dim: int = 1, sigma: float = 1.0
    ) -> None:
        super().__init__(in_dim, out_dim, sigma)
        if not callable(fn):
            raise ValueError(f"fn must be callable, got {type(fn).__name__}")
        self.fn = fn

    def core(self, z: Tensor) -> Tensor:
        out = self.fn(z)
        if out.shape != (*z.shape[:-1], self.out_dim):
            raise ValueError(
                f"function mechanism returned shape {tuple(out.shape)}, expected "
                f"{(*z.shape[:-1], self.out_dim)}"
            )
        return out


_REGISTRY: dict[str, type[Mechanism]] = {"mlp": MLPMechanism, "linear": LinearMechanism}


def make_mechanism(config: dict[str, Any]) -> Mechanism:
    """Build a mechanism from :meth:`Mechanism.config` output."""
    config = dict(config)
    kind = config.pop("kind", None)
    if kind not in _REGISTRY:
        raise ValueError(f"mechanism kind {kind!r} cannot be built; expected one of {sorted(_REGISTRY)}")
    return _REGISTRY[kind](**config)
