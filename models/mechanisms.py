"""Local structural mechanisms f_i and their noise scales (thesis Eq. 4.31, 5.3-5.4).

Every mechanism defines a Gaussian assignment with a location and a scale,

    X_i = f_i(pa_i) + sigma_i(pa_i) * eps_i,   eps_i ~ N(0, I),

and :meth:`Mechanism.loc_scale` returns both. The mechanisms here are homoscedastic:
``sigma_i(pa_i) = sigma_i = exp(log_sigma)`` is learned per component, and
``f_i(z) = out_loc + out_scale * g((z - in_loc) / in_scale)``. The affine normalisers are
buffers that :func:`inference.fit` sets from data; ``g`` is the learned core (MLP or
linear). :mod:`models.heteroscedastic` predicts ``sigma_i(pa_i)`` as well, and
:mod:`models.ensemble` combines K mechanisms into one site.

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
    "mechanism_classes",
]


class Tanh(nn.Module):
    """``tanh(x) = 2 sigmoid(2 x) - 1``, elementwise, any shape.

    The same function as ``torch.tanh`` (within 2e-7 in float32), evaluated through the
    sigmoid, which CPU builds of torch vectorise better: about 3x faster on the tanh MLPs
    that every query evaluates.
    """

    def forward(self, x: Tensor) -> Tensor:
        """``(...) -> (...)``."""
        y = torch.sigmoid(2 * x)
        if y.requires_grad:
            return 2 * y - 1
        return y.mul_(2).sub_(1)


ACTIVATIONS: dict[str, type[nn.Module]] = {
    "tanh": Tanh,
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


_CLASSES: dict[str, type[Mechanism]] = {}


class Mechanism(nn.Module):
    """Base class: a parent-conditioned Gaussian assignment ``X = loc(pa) + scale(pa) * eps``.

    Subclasses define :meth:`core` (the map on normalised parents). The base class is
    homoscedastic, ``scale(pa) = sigma = exp(log_sigma)``; a subclass that predicts its own
    scale passes ``sigma=None`` (no ``log_sigma`` parameter) and overrides :meth:`loc_scale`.

    Args:
        in_dim: total dimension of the concatenated parents.
        out_dim: dimension of the child variable.
        sigma: initial residual standard deviation, > 0, in the child's units; None for a
            mechanism that predicts its scale.

    Shapes:
        ``forward``: ``(..., in_dim) -> (..., out_dim)``; ``loc_scale``: ``(..., in_dim) ->
        ((..., out_dim), (..., out_dim))``; ``sigma``: ``(out_dim,)``.
    """

    kind: ClassVar[str] = ""
    #: Constructor arguments that :func:`make_mechanism` accepts besides ``kind``.
    config_keys: ClassVar[frozenset[str]] = frozenset()
    #: True (set in a class's own body) registers the class with :func:`make_mechanism`.
    serialisable: ClassVar[bool] = False

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if cls.__dict__.get("serialisable", False):
            _CLASSES[cls.kind] = cls

    def __init__(self, in_dim: int, out_dim: int, sigma: float | None = 1.0) -> None:
        super().__init__()
        in_dim = check_int("in_dim", in_dim, minimum=1)
        out_dim = check_int("out_dim", out_dim, minimum=1)
        self.in_dim = in_dim
        self.out_dim = out_dim
        self.register_buffer("in_loc", torch.zeros(in_dim))
        self.register_buffer("in_scale", torch.ones(in_dim))
        self.register_buffer("out_loc", torch.zeros(out_dim))
        self.register_buffer("out_scale", torch.ones(out_dim))
        if sigma is None:
            self.register_parameter("log_sigma", None)
        else:
            sigma = check_float("sigma", sigma, minimum=0.0, min_open=True)
            self.log_sigma = nn.Parameter(torch.full((out_dim,), math.log(sigma)))

    # ------------------------------------------------------------------ properties
    @property
    def heteroscedastic(self) -> bool:
        """True when the scale depends on the parents (then :attr:`sigma` is undefined)."""
        return self.log_sigma is None

    @property
    def trainable(self) -> bool:
        """True when :func:`inference.fit` may train this mechanism (fixed functions are not)."""
        return True

    @property
    def size(self) -> int:
        """Number of members K (1 unless an ensemble)."""
        return 1

    # ------------------------------------------------------------------ evaluation
    def core(self, z: Tensor) -> Tensor:  # pragma: no cover - abstract
        """The map g on normalised parents z: ``(..., in_dim) -> (..., out_dim)``; subclasses define it."""
        raise NotImplementedError

    def check_input(self, parents: Any) -> Tensor:
        """``parents`` as a floating tensor of the mechanism's dtype, last dim ``in_dim``."""
        if not isinstance(parents, Tensor) or parents.dtype != self.in_loc.dtype:
            parents = as_float_tensor(parents, "mechanism input", self.in_loc.dtype)
        if parents.ndim == 0 or parents.shape[-1] != self.in_dim:
            last = parents.shape[-1] if parents.ndim else "none (0-d)"
            raise ValueError(
                f"mechanism input has last dim {last}, expected {self.in_dim} "
                f"(concatenated parent dims; shape {tuple(parents.shape)})"
            )
        return parents

    def forward(self, parents: Tensor) -> Tensor:
        """The location f_i: ``(..., in_dim) -> (..., out_dim)``; floating input of another dtype is converted."""
        parents = self.check_input(parents)
        z = (parents - self.in_loc) / self.in_scale
        return self.out_loc + self.out_scale * self.core(z)

    def loc_scale(self, parents: Tensor) -> tuple[Tensor, Tensor]:
        """``(f_i(pa), sigma_i(pa))``, each ``(..., out_dim)`` in the child's units.

        The site samples ``X ~ Normal(loc, scale)``. Homoscedastic mechanisms return
        their sigma broadcast to the shape of loc.
        """
        loc = self(parents)
        return loc, self.sigma.expand_as(loc)

    def member_loc_scale(self, parents: Tensor, paired: bool = False) -> tuple[Tensor, Tensor]:
        """Per-member ``(loc, scale)``, each ``(K, ..., out_dim)``; K = 1 here.

        Args:
            parents: ``(..., in_dim)`` shared by all members, or with ``paired``
                ``(K, ..., in_dim)`` where member k reads ``parents[k]``.
            paired: see ``parents``.
        """
        loc, scale = self.loc_scale(parents)
        return (loc, scale) if paired else (loc.unsqueeze(0), scale.unsqueeze(0))

    def penalty(self) -> Tensor:
        """A regulariser that :func:`inference.fit` adds to the training loss (0 here)."""
        return self.in_loc.new_zeros(())

    # ------------------------------------------------------------------ setting values
    @property
    def sigma(self) -> Tensor:
        """Residual standard deviation sigma_i, shape ``(out_dim,)``, in the child's units.

        Raises:
            ValueError: the mechanism is heteroscedastic (its scale depends on the parents).
        """
        if self.log_sigma is None:
            raise ValueError(
                f"a {type(self).__name__} is heteroscedastic: its scale depends on the parents; "
                "use loc_scale(parents) (or WorldModel.predict_scale) instead of sigma"
            )
        return self.log_sigma.exp()

    def set_sigma(self, sigma: Any) -> None:
        """Set sigma_i: ``(out_dim,)`` values > 0 in the child's units (a scalar sets all)."""
        if self.log_sigma is None:
            raise ValueError(
                f"a {type(self).__name__} is heteroscedastic: it predicts its scale, which cannot be set"
            )
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

    # ------------------------------------------------------------------ persistence
    def config(self) -> dict[str, Any]:
        """JSON-compatible constructor arguments; used by :mod:`models.io`."""
        return {"kind": self.kind, "in_dim": self.in_dim, "out_dim": self.out_dim}

    @classmethod
    def from_config(cls, config: Mapping[str, Any], seed: Seed = 0) -> Mechanism:
        """Build from :meth:`config` output without ``kind`` (keys checked by :func:`make_mechanism`)."""
        return cls(**config, seed=seed)

    def input_weights(self) -> tuple[str, ...]:
        """``state_dict`` keys of the weights that read the normalised parents (columns = inputs).

        :meth:`models.WorldModel.with_graph` rewires these when parents change; empty
        when the mechanism cannot be rewired.
        """
        return ()


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
    serialisable = True
    config_keys = frozenset({"in_dim", "out_dim", "hidden", "activation", "sigma"})

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

    def input_weights(self) -> tuple[str, ...]:
        """The first layer's weight, ``net.0.weight``."""
        return ("net.0.weight",)


class LinearMechanism(Mechanism):
    """f_i(pa) = W pa + b, W of shape ``(out_dim, in_dim)``.

    Use :meth:`from_coefficients` to set a known linear SCM exactly.

    Args:
        in_dim, out_dim, sigma: see :class:`Mechanism`.
        seed: int or ``torch.Generator`` for the initial W and b; None draws them from
            the global torch RNG.
    """

    kind = "linear"
    serialisable = True
    config_keys = frozenset({"in_dim", "out_dim", "sigma"})

    def __init__(self, in_dim: int, out_dim: int = 1, sigma: float = 1.0, *, seed: Seed = None) -> None:
        super().__init__(in_dim, out_dim, sigma)
        self.linear = _linear(self.in_dim, self.out_dim, as_generator(seed))

    def core(self, z: Tensor) -> Tensor:
        """``W z + b`` on normalised parents: ``(..., in_dim) -> (..., out_dim)``."""
        return self.linear(z)

    def input_weights(self) -> tuple[str, ...]:
        """The weight W, ``linear.weight``."""
        return ("linear.weight",)

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

    Not serialisable: :func:`models.io.save` refuses models that contain one. Not
    trainable: :func:`inference.fit` leaves it (and its sigma) as given.
    """

    kind = "function"

    def __init__(
        self, fn: Callable[[Tensor], Tensor], in_dim: int, out_dim: int = 1, sigma: float = 1.0
    ) -> None:
        if not callable(fn):
            raise ValueError(f"fn must be callable, got {type(fn).__name__}")
        super().__init__(in_dim, out_dim, sigma)
        self.fn = fn

    @property
    def trainable(self) -> bool:
        """False: a fixed function is given, not learned."""
        return False

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


def mechanism_classes() -> dict[str, type[Mechanism]]:
    """The serialisable mechanism classes by ``kind``: what :func:`make_mechanism` can build.

    A subclass of :class:`Mechanism` that sets ``serialisable = True`` in its own body is
    registered under its ``kind`` when it is defined (``models`` imports all of its own).
    """
    return dict(_CLASSES)


def make_mechanism(config: Mapping[str, Any], seed: Seed = 0) -> Mechanism:
    """Build a mechanism from :meth:`Mechanism.config` output.

    Args:
        config: ``{"kind": "mlp" | "linear" | "hetero" | "ensemble", "in_dim": ..., ...}``
            (an ensemble's config nests its members' configs).
        seed: initial weights (normally overwritten by a ``state_dict``); the default
            seed 0 keeps the global RNG untouched.

    Raises:
        ValueError: not a mapping, an unknown kind or key, or a missing ``in_dim``.
    """
    if not isinstance(config, Mapping):
        raise ValueError(f"mechanism config must be a mapping, got {type(config).__name__}")
    config = dict(config)
    registry = mechanism_classes()
    kind = config.pop("kind", None)
    if not isinstance(kind, str) or kind not in registry:
        raise ValueError(f"mechanism kind {kind!r} cannot be built; expected one of {sorted(registry)}")
    cls = registry[kind]
    unknown = sorted(str(k) for k in set(config) - cls.config_keys)
    if unknown:
        raise ValueError(
            f"{kind} mechanism config has unknown keys {unknown}; expected {sorted(cls.config_keys)}"
        )
    if "in_dim" in cls.config_keys and "in_dim" not in config:
        raise ValueError(f"{kind} mechanism config needs 'in_dim', got keys {sorted(config)}")
    return cls.from_config(config, seed=seed)
