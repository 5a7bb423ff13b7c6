"""Local structural mechanisms f_i and their noise scales sigma_i (thesis Eq. 4.31, 5.3-5.4).

Every mechanism defines the additive Gaussian assignment

    X_i = f_i(pa_i) + sigma_i * eps_i,   eps_i ~ N(0, I),

with ``f_i(z) = out_loc + out_scale * g((z - in_loc) / in_scale)``. The affine
normalisers are buffers that :func:`inference.fit` sets from data; ``g`` is the learned
core (MLP or linear), and ``sigma_i = exp(log_sigma)`` is learned per component.

Weights are initialised as by ``torch.nn.Linear`` (uniform on +-1/sqrt(fan_in)). With
``seed`` (an int or a ``torch.Generator``) they are drawn from a local generator and the
global torch RNG is not touched; without it they come from the global torch RNG.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any, ClassVar

import torch
from torch import Tensor, nn

from models.checks import (
    as_float_tensor,
    check_choice,
    check_finite_tensor,
    check_float,
    check_hidden,
    check_int,
    check_seed,
)

__all__ = [
    "ACTIVATIONS",
    "FunctionMechanism",
    "LinearMechanism",
    "MLPMechanism",
    "Mechanism",
    "as_generator",
    "make_mechanism",
]

ACTIVATIONS: dict[str, type[nn.Module]] = {
    "tanh": nn.Tanh,
    "relu": nn.ReLU,
    "elu": nn.ELU,
    "silu": nn.SiLU,
    "softplus": nn.Softplus,
}


Seed = int | torch.Generator | None


def as_generator(seed: Seed) -> torch.Generator | None:
    """A local generator from an int seed; a Generator is used as is; None stays None."""
    if seed is None or isinstance(seed, torch.Generator):
        return seed
    return torch.Generator().manual_seed(check_seed("seed", seed))


def _linear(in_dim: int, out_dim: int, generator: torch.Generator | None) -> nn.Linear:
    """``nn.Linear`` with its default initialisation, drawn from ``generator`` if given.

    With a generator the same draws are made as ``nn.Linear`` makes after
    ``torch.manual_seed``, without touching the global RNG.
    """
    if generator is None:
        return nn.Linear(in_dim, out_dim)
    layer = nn.utils.skip_init(nn.Linear, in_dim, out_dim)
    bound = 1.0 / math.sqrt(in_dim)
    with torch.no_grad():
        nn.init.kaiming_uniform_(layer.weight, a=math.sqrt(5), generator=generator)
        nn.init.uniform_(layer.bias, -bound, bound, generator=generator)
    return layer


def _vector(value: Any, n: int, what: str, allow_scalar: bool = False) -> Tensor:
    """A finite ``(n,)`` tensor; a 0-d ``value`` fills all n entries only if ``allow_scalar``."""
    t = as_float_tensor(value, what)
    if t.ndim == 0 and allow_scalar:
        t = t.expand(n)
    if t.ndim > 1 or t.numel() != n:
        raise ValueError(f"{what} has {t.numel()} entries, expected {n} (got shape {tuple(t.shape)})")
    check_finite_tensor(what, t)
    return t.detach().clone()


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
        in_dim = check_int("in_dim", in_dim, minimum=1)
        out_dim = check_int("out_dim", out_dim, minimum=1)
        sigma = check_float("sigma", sigma, minimum=0.0, min_open=True)
        self.in_dim = in_dim
        self.out_dim = out_dim
        self.register_buffer("in_loc", torch.zeros(in_dim))
        self.register_buffer("in_scale", torch.ones(in_dim))
        self.register_buffer("out_loc", torch.zeros(out_dim))
        self.register_buffer("out_scale", torch.ones(out_dim))
        self.log_sigma = nn.Parameter(torch.full((out_dim,), math.log(sigma)))

    def core(self, z: Tensor) -> Tensor:  # pragma: no cover - abstract
        """The map g on normalised parents z: ``(..., in_dim) -> (..., out_dim)``; subclasses define it."""
        raise NotImplementedError

    def forward(self, parents: Tensor) -> Tensor:
        """f_i: ``(..., in_dim) -> (..., out_dim)``; floating input of another dtype is converted."""
        if not isinstance(parents, Tensor) or parents.dtype != self.in_loc.dtype:
            parents = as_float_tensor(parents, "mechanism input", self.in_loc.dtype)
        if parents.ndim == 0 or parents.shape[-1] != self.in_dim:
            last = parents.shape[-1] if parents.ndim else "none (0-d)"
            raise ValueError(
                f"mechanism input has last dim {last}, expected {self.in_dim} "
                f"(concatenated parent dims; shape {tuple(parents.shape)})"
            )
        z = (parents - self.in_loc) / self.in_scale
        return self.out_loc + self.out_scale * self.core(z)

    @property
    def sigma(self) -> Tensor:
        """Residual standard deviation sigma_i, shape ``(out_dim,)``."""
        return self.log_sigma.exp()

    def set_sigma(self, sigma: Any) -> None:
        """Set sigma_i: ``(out_dim,)`` values > 0 in the child's units (a scalar sets all)."""
        s = _vector(sigma, self.out_dim, "sigma", allow_scalar=True)
        if not (s > 0).all():
            raise ValueError(f"sigma must be > 0, got {s.tolist()}")
        with torch.no_grad():
            self.log_sigma.copy_(s.log())

    def set_normalization(self, in_loc: Any, in_scale: Any, out_loc: Any, out_scale: Any) -> None:
        """Set the affine normalisers: ``in_*`` of shape ``(in_dim,)``, ``out_*`` ``(out_dim,)``, scales > 0."""
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

    ``g(z) = W_L act(... act(W_1 z + b_1) ...) + b_L``.

    Args:
        in_dim, out_dim, sigma: see :class:`Mechanism`.
        hidden: hidden layer widths (ints >= 1; empty for an affine map).
        activation: one of ``ACTIVATIONS``.
        seed: int or ``torch.Generator`` for the initial weights; None draws them from
            the global torch RNG.
    """

    kind = "mlp"

    def __init__(
        self,
        in_dim: int,
        out_dim: int = 1,
        hidden: Sequence[int] = (32, 32),
        activation: str = "tanh",
        sigma: float = 1.0,
        *,
        seed: Seed = None,
    ) -> None:
        super().__init__(in_dim, out_dim, sigma)
        activation = check_choice("activation", activation, sorted(ACTIVATIONS))
        hidden = check_hidden(hidden)
        generator = as_generator(seed)
        self.hidden = hidden
        self.activation = activation
        layers: list[nn.Module] = []
        width = self.in_dim
        for h in hidden:
            layers += [_linear(width, h, generator), ACTIVATIONS[activation]()]
            width = h
        layers.append(_linear(width, self.out_dim, generator))
        self.net = nn.Sequential(*layers)

    def core(self, z: Tensor) -> Tensor:
        """The MLP g(z) on normalised parents: ``(..., in_dim) -> (..., out_dim)``."""
        return self.net(z)

    def config(self) -> dict[str, Any]:
        """JSON-compatible constructor arguments, including ``hidden`` and ``activation``."""
        return {**super().config(), "hidden": list(self.hidden), "activation": self.activation}


class LinearMechanism(Mechanism):
    """f_i(pa) = W pa + b, W of shape ``(out_dim, in_dim)``.

    Use :meth:`from_coefficients` to set a known linear SCM exactly.

    Args:
        in_dim, out_dim, sigma: see :class:`Mechanism`.
        seed: int or ``torch.Generator`` for the initial W and b; None draws them from
            the global torch RNG.
    """

    kind = "linear"

    def __init__(self, in_dim: int, out_dim: int = 1, sigma: float = 1.0, *, seed: Seed = None) -> None:
        super().__init__(in_dim, out_dim, sigma)
        self.linear = _linear(self.in_dim, self.out_dim, as_generator(seed))

    def core(self, z: Tensor) -> Tensor:
        """``W z + b`` on normalised parents: ``(..., in_dim) -> (..., out_dim)``."""
        return self.linear(z)

    @classmethod
    def from_coefficients(cls, weight: Any, bias: Any = 0.0, sigma: Any = 1.0) -> LinearMechanism:
        """Exact linear mechanism ``W pa + b``.

        ``weight`` has shape (out_dim, in_dim); a scalar means 1 -> 1 and a vector means
        in_dim -> 1. ``bias`` and ``sigma`` are per output component (a scalar fills all).
        All entries must be finite (and sigma > 0). The global RNG is not touched.
        """
        w = as_float_tensor(weight, "weight").detach()
        if w.ndim == 0:
            w = w.reshape(1, 1)
        elif w.ndim == 1:
            w = w.reshape(1, -1)
        if w.ndim != 2 or w.numel() == 0:
            raise ValueError(f"weight has shape {tuple(w.shape)}, expected (out_dim, in_dim) with both >= 1")
        check_finite_tensor("weight", w)
        mech = cls(w.shape[1], w.shape[0], seed=0)  # the seeded weights are overwritten below
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
        if not callable(fn):
            raise ValueError(f"fn must be callable, got {type(fn).__name__}")
        super().__init__(in_dim, out_dim, sigma)
        self.fn = fn

    def core(self, z: Tensor) -> Tensor:
        """``fn(z)`` on normalised parents, checked to be finite and ``(..., out_dim)``."""
        out = self.fn(z)
        if not isinstance(out, Tensor) or out.shape != (*z.shape[:-1], self.out_dim):
            got = tuple(out.shape) if isinstance(out, Tensor) else type(out).__name__
            raise ValueError(
                f"function mechanism returned {got}, expected a tensor of shape {(*z.shape[:-1], self.out_dim)}"
            )
        if not bool(torch.isfinite(out).all()):
            raise ValueError("function mechanism returned NaN or inf; check fn on these inputs")
        return out


_REGISTRY: dict[str, type[Mechanism]] = {"mlp": MLPMechanism, "linear": LinearMechanism}


_CONFIG_KEYS = {
    "mlp": {"in_dim", "out_dim", "hidden", "activation", "sigma"},
    "linear": {"in_dim", "out_dim", "sigma"},
}


def make_mechanism(config: Mapping[str, Any], seed: Seed = 0) -> Mechanism:
    """Build a mechanism from :meth:`Mechanism.config` output.

    Args:
        config: ``{"kind": "mlp" | "linear", "in_dim": ..., ...}``.
        seed: initial weights (normally overwritten by a ``state_dict``); the default
            seed 0 keeps the global RNG untouched.
    """
    if not isinstance(config, Mapping):
        raise ValueError(f"mechanism config must be a mapping, got {type(config).__name__}")
    config = dict(config)
    kind = config.pop("kind", None)
    if not isinstance(kind, str) or kind not in _REGISTRY:
        raise ValueError(f"mechanism kind {kind!r} cannot be built; expected one of {sorted(_REGISTRY)}")
    unknown = sorted(set(config) - _CONFIG_KEYS[kind])
    if unknown:
        raise ValueError(
            f"{kind} mechanism config has unknown keys {unknown}; expected {sorted(_CONFIG_KEYS[kind])}"
        )
    if "in_dim" not in config:
        raise ValueError(f"{kind} mechanism config needs 'in_dim', got keys {sorted(config)}")
    return _REGISTRY[kind](**config, seed=seed)
