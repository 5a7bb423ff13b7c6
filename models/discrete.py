"""Discrete sites: Bernoulli and categorical mechanisms and their Gumbel-max noise.

A discrete variable has ``dim = 1`` and takes integer codes ``0 .. K-1`` stored as floats in
``(N, 1)`` tensors like every other value (K = 2 for a Bernoulli site: 0 or 1). Its site is

    X_i ~ Categorical(softmax(l_i(pa_i))),      l_i(pa) = g((pa - in_loc) / in_scale),

with ``g`` a linear map or an MLP (logistic or softmax regression; a Bernoulli site has one
logit ``l`` and ``l_i = (0, l)``). As a structural assignment this is the Gumbel-max SCM
(Oberst and Sontag 2019):

    X_i = argmax_k ( l_ik(pa_i) + G_ik ),      G_ik ~ Gumbel(0, 1) i.i.d.,

so the exogenous noise of a discrete site is a ``(N, K)`` tensor of standard Gumbels. Given
an observed category x, the posterior of G is sampled exactly by the top-down construction
(:func:`gumbel_posterior`): the maximum ``M = max_k (l_k + G_k) ~ Gumbel(logsumexp l)``,
``l_x + G_x = M``, and every other ``l_j + G_j`` is a ``Gumbel(l_j)`` truncated to ``< M``.
Replaying that noise under other parents gives the counterfactual category
(:func:`gumbel_max`). Zero noise replays the mode, ``argmax_k l_k``: the discrete analogue of
the expected residual.

:class:`CategoricalCode` is the site's Pyro distribution: batch ``(..., N)``, event ``(1,)``,
float codes, with ``enumerate_support`` for Pyro's enumeration (``TraceEnum_ELBO``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, ClassVar

import torch
from pyro.distributions import TorchDistribution, constraints
from torch import Tensor

from models.checks import as_float_tensor, check_choice, check_finite_tensor, check_hidden, check_int
from models.mechanisms import ACTIVATIONS, Mechanism, Seed, _linear, _vector, as_generator

__all__ = [
    "BernoulliMechanism",
    "CategoricalCode",
    "CategoricalMechanism",
    "DiscreteMechanism",
    "check_codes",
    "gumbel",
    "gumbel_max",
    "gumbel_posterior",
]

_TINY = 1e-12


class CategoricalCode(TorchDistribution):
    """``Categorical(softmax(logits))`` over float codes with a trailing event dim of 1.

    Args:
        logits: ``(..., N, K)`` unnormalised log-probabilities, K >= 2.

    Shapes:
        batch ``(..., N)``, event ``(1,)``; values ``(..., N, 1)`` floats in ``{0, .., K-1}``.
    """

    arg_constraints: ClassVar[dict[str, Any]] = {"logits": constraints.real_vector}
    has_enumerate_support = True

    def __init__(self, logits: Tensor, validate_args: bool | None = None) -> None:
        if logits.ndim < 1 or logits.shape[-1] < 2:
            raise ValueError(f"logits have shape {tuple(logits.shape)}, expected (..., K) with K >= 2")
        self.logits = logits - logits.logsumexp(-1, keepdim=True)
        super().__init__(logits.shape[:-1], torch.Size([1]), validate_args=validate_args)

    @property
    def categories(self) -> int:
        """K, the number of categories."""
        return self.logits.shape[-1]

    @constraints.dependent_property(is_discrete=True, event_dim=1)
    def support(self) -> Any:
        """Integer codes ``0 .. K-1`` in a trailing dim of 1."""
        return constraints.independent(constraints.integer_interval(0, self.categories - 1), 1)

    @property
    def probs(self) -> Tensor:
        """``(..., N, K)`` category probabilities."""
        return self.logits.exp()

    @property
    def mean(self) -> Tensor:
        """``(..., N, 1)`` expected code ``sum_k k p_k``."""
        k = torch.arange(self.categories, dtype=self.logits.dtype)
        return (self.probs * k).sum(-1, keepdim=True)

    @property
    def variance(self) -> Tensor:
        """``(..., N, 1)`` variance of the code."""
        k = torch.arange(self.categories, dtype=self.logits.dtype)
        return (self.probs * k**2).sum(-1, keepdim=True) - self.mean**2

    def expand(self, batch_shape: Any, _instance: Any = None) -> CategoricalCode:
        """The same distribution broadcast to ``batch_shape``."""
        batch_shape = torch.Size(batch_shape)
        return CategoricalCode(self.logits.expand(*batch_shape, self.categories))

    def sample(self, sample_shape: Any = ()) -> Tensor:
        """Codes ``(*sample_shape, ..., N, 1)`` drawn with torch's global RNG."""
        with torch.no_grad():
            idx = torch.distributions.Categorical(logits=self.logits).sample(torch.Size(sample_shape))
        return idx.unsqueeze(-1).to(self.logits.dtype)

    def log_prob(self, value: Tensor) -> Tensor:
        """``log p(value)``: ``(..., N, 1)`` codes -> ``(..., N)``, broadcasting like Pyro's enumeration."""
        if self._validate_args:
            self._validate_sample(value)
        idx = value[..., 0].long()
        shape = torch.broadcast_shapes(idx.shape, self.batch_shape)
        logits = self.logits.expand(*shape, self.categories)
        return logits.gather(-1, idx.expand(shape).unsqueeze(-1)).squeeze(-1)

    def enumerate_support(self, expand: bool = True) -> Tensor:
        """Every code: ``(K, ..., N, 1)`` (``(K, 1, .., 1)`` without ``expand``)."""
        values = torch.arange(self.categories, dtype=self.logits.dtype)
        values = values.reshape((self.categories,) + (1,) * len(self.batch_shape) + (1,))
        if expand:
            values = values.expand((self.categories, *self.batch_shape, 1))
        return values

    def entropy(self) -> Tensor:
        """``(..., N)`` entropy in nats."""
        return -(self.probs * self.logits).sum(-1)


# ---------------------------------------------------------------------------- Gumbel-max
def gumbel(shape: Sequence[int], generator: torch.Generator | None, dtype: torch.dtype) -> Tensor:
    """Standard Gumbel draws ``-log(-log U)``, ``U ~ Uniform(0, 1)``, from ``generator``."""
    u = torch.rand(tuple(shape), generator=generator, dtype=dtype).clamp(_TINY, 1 - 1e-7)
    return -torch.log(-torch.log(u))


def gumbel_max(logits: Tensor, noise: Tensor) -> Tensor:
    """``argmax_k (logits_k + noise_k)`` as float codes: ``(..., K), (..., K) -> (..., 1)``."""
    return (logits + noise).argmax(-1, keepdim=True).to(logits.dtype)


def gumbel_posterior(logits: Tensor, value: Tensor, generator: torch.Generator | None) -> Tensor:
    """A draw of standard Gumbel noise G given ``argmax_k (logits_k + G_k) = value``.

    The top-down construction (Maddison et al. 2014; Oberst and Sontag 2019), exact: with
    ``l = logits - logsumexp(logits)``, ``M ~ Gumbel(0, 1)`` is the maximum of ``l + G``;
    the observed category gets ``l_x + G_x = M`` and every other category
    ``l_j + G_j = -log(exp(-M) + exp(-(l_j + E_j)))`` with ``E_j ~ Gumbel(0, 1)``, a
    ``Gumbel(l_j)`` truncated to values below M.

    Args:
        logits: ``(..., K)`` logits of the site at the factual parents.
        value: ``(..., 1)`` observed codes (broadcast against ``logits``).
        generator: source of randomness (None: torch's global RNG).

    Returns:
        ``(..., K)`` standard Gumbel noise consistent with ``value``.
    """
    value = value.expand(*logits.shape[:-1], 1)
    log_p = logits - logits.logsumexp(-1, keepdim=True)
    top = gumbel((*logits.shape[:-1], 1), generator, logits.dtype)
    other = log_p + gumbel(logits.shape, generator, logits.dtype)
    truncated = -torch.logaddexp(-top, -other)
    chosen = torch.nn.functional.one_hot(value[..., 0].long(), logits.shape[-1]).bool()
    perturbed = torch.where(chosen, top.expand_as(log_p), truncated)
    return perturbed - log_p


def check_codes(what: str, value: Tensor, categories: int) -> Tensor:
    """Refuse values of a discrete site that are not integer codes ``0 .. K-1``.

    Raises:
        ValueError: naming ``what``, the first bad value and its index, and the allowed codes.
    """
    v = value.detach()
    bad = (v != v.round()) | (v < 0) | (v > categories - 1)
    if bool(bad.any()):
        first = tuple(int(i) for i in torch.nonzero(bad)[0]) if v.ndim else ()
        got = float(v[first]) if first else float(v)
        allowed = "0 or 1 (a Bernoulli site)" if categories == 2 else f"an integer code 0 .. {categories - 1}"
        raise ValueError(
            f"{what} has {int(bad.sum())} values that are not {allowed} (first: {got:g} at index {first}); "
            "discrete sites take category codes as floats"
        )
    return value


# ---------------------------------------------------------------------------- mechanisms
class DiscreteMechanism(Mechanism):
    """Base of the discrete mechanisms: logits ``l(pa)`` over K categories of a dim-1 site.

    ``forward`` returns the mode ``argmax_k l_k`` as a float code (the value under zero
    Gumbel noise); :meth:`logits` and :meth:`distribution` give the site's law. There is no
    location-scale form: :meth:`loc_scale` and :attr:`sigma` raise.

    Args:
        in_dim: total width of the encoded parents (categorical parents with K > 2
            categories are one-hot, K columns; see :meth:`models.WorldModel.parent_width`).
        categories: K >= 2.
        hidden: hidden widths of the logit MLP; ``()`` for logistic / softmax regression.
        activation: one of ``ACTIVATIONS``.
        seed: int or ``torch.Generator`` for the initial weights; None draws them from
            the global torch RNG.
    """

    config_keys = frozenset({"in_dim", "hidden", "activation"})

    def __init__(
        self,
        in_dim: int,
        categories: int,
        hidden: Sequence[int] = (),
        activation: str = "tanh",
        *,
        seed: Seed = None,
    ) -> None:
        super().__init__(in_dim, 1, sigma=None)
        self.categories = check_int("categories", categories, minimum=2)
        self.hidden = check_hidden(hidden)
        self.activation = check_choice("activation", activation, sorted(ACTIVATIONS))
        generator = as_generator(seed)
        layers: list[torch.nn.Module] = []
        width = self.in_dim
        for h in self.hidden:
            layers += [_linear(width, h, generator), ACTIVATIONS[self.activation]()]
            width = h
        layers.append(_linear(width, 1 if self.categories == 2 else self.categories, generator))
        self.net = torch.nn.Sequential(*layers)

    @property
    def heteroscedastic(self) -> bool:
        """False: a discrete site has no scale."""
        return False

    @property
    def sigma(self) -> Tensor:
        """Undefined for a discrete site.

        Raises:
            ValueError: always.
        """
        raise ValueError(
            f"a {type(self).__name__} is discrete ({self.categories} categories): it has no sigma; "
            "use logits(parents) or distribution(parents)"
        )

    def set_sigma(self, sigma: Any) -> None:
        """Refused: a discrete site has no sigma."""
        raise ValueError(f"a {type(self).__name__} is discrete: it has no sigma to set")

    def core(self, z: Tensor) -> Tensor:
        """Logits on normalised parents: ``(..., in_dim) -> (..., K)``."""
        raw = self.net(z)
        if self.categories == 2:
            return torch.cat([torch.zeros_like(raw), raw], -1)
        return raw

    def logits(self, parents: Tensor) -> Tensor:
        """``l(pa)``: ``(..., in_dim) -> (..., K)`` (a Bernoulli site: ``(0, logit)``)."""
        parents = self.check_input(parents)
        return self.core((parents - self.in_loc) / self.in_scale)

    def distribution(self, parents: Tensor) -> CategoricalCode:
        """The site's law given the encoded parents: batch ``(..., N)``, event ``(1,)``."""
        return CategoricalCode(self.logits(parents))

    def forward(self, parents: Tensor) -> Tensor:
        """The mode ``argmax_k l_k(pa)`` as float codes ``(..., 1)``."""
        logits = self.logits(parents)
        return logits.argmax(-1, keepdim=True).to(logits.dtype)

    def loc_scale(self, parents: Tensor) -> tuple[Tensor, Tensor]:
        """Refused: a discrete site is not location-scale.

        Raises:
            ValueError: always.
        """
        raise ValueError(
            f"a {type(self).__name__} is discrete: it has no (loc, scale); use logits(parents) "
            "and the Gumbel-max noise of models.discrete"
        )

    def member_loc_scale(self, parents: Tensor, paired: bool = False) -> tuple[Tensor, Tensor]:
        """Refused, as :meth:`loc_scale`."""
        return self.loc_scale(parents)

    def set_normalization(self, in_loc: Any, in_scale: Any, out_loc: Any = 0.0, out_scale: Any = 1.0) -> None:
        """Set the input normalisers (``(in_dim,)``, scales > 0); the output ones stay the identity."""
        del out_loc, out_scale
        super().set_normalization(in_loc, in_scale, torch.zeros(1), torch.ones(1))

    def config(self) -> dict[str, Any]:
        """JSON-compatible constructor arguments."""
        return {
            "kind": self.kind,
            "in_dim": self.in_dim,
            "hidden": list(self.hidden),
            "activation": self.activation,
        }

    def input_weights(self) -> tuple[str, ...]:
        """The first layer's weight, ``net.0.weight``."""
        return ("net.0.weight",)

    def _set_affine(self, weight: Tensor, bias: Tensor) -> None:
        if self.hidden:
            raise ValueError("coefficients set a linear logit map; this mechanism has hidden layers")
        with torch.no_grad():
            self.net[0].weight.copy_(weight)
            self.net[0].bias.copy_(bias)


class BernoulliMechanism(DiscreteMechanism):
    """A binary site: ``P(X = 1 | pa) = sigmoid(logit(pa))`` (logistic regression or MLP).

    Args:
        in_dim, hidden, activation, seed: see :class:`DiscreteMechanism` (K = 2).
    """

    kind = "bernoulli"
    serialisable = True

    def __init__(
        self, in_dim: int, hidden: Sequence[int] = (), activation: str = "tanh", *, seed: Seed = None
    ) -> None:
        super().__init__(in_dim, 2, hidden, activation, seed=seed)

    @classmethod
    def from_coefficients(cls, weight: Any, bias: Any = 0.0) -> BernoulliMechanism:
        """Exact logistic mechanism ``logit P(X = 1 | pa) = w . pa + b``.

        Args:
            weight: ``(in_dim,)`` finite coefficients (a scalar for one parent).
            bias: finite intercept.
        """
        w = as_float_tensor(weight, "weight").detach().reshape(-1)
        if w.numel() == 0:
            raise ValueError("weight is empty; expected (in_dim,) coefficients")
        check_finite_tensor("weight", w)
        mech = cls(w.numel(), seed=0)
        mech._set_affine(w.reshape(1, -1), _vector(bias, 1, "bias", allow_scalar=True))
        return mech


class CategoricalMechanism(DiscreteMechanism):
    """A K-category site: ``P(X = k | pa) = softmax(l(pa))_k`` (softmax regression or MLP).

    Args:
        in_dim, categories, hidden, activation, seed: see :class:`DiscreteMechanism`.
    """

    kind = "categorical"
    serialisable = True
    config_keys = frozenset({"in_dim", "categories", "hidden", "activation"})

    def config(self) -> dict[str, Any]:
        """JSON-compatible constructor arguments, including ``categories``."""
        return {**super().config(), "categories": self.categories}

    @classmethod
    def from_coefficients(cls, weight: Any, bias: Any = 0.0) -> CategoricalMechanism:
        """Exact softmax mechanism ``l(pa) = W pa + b``.

        Args:
            weight: ``(K, in_dim)`` finite coefficients, K >= 2.
            bias: ``(K,)`` finite intercepts (a scalar fills all).
        """
        w = as_float_tensor(weight, "weight").detach()
        if w.ndim != 2 or w.shape[0] < 2 or w.shape[1] < 1:
            raise ValueError(f"weight has shape {tuple(w.shape)}, expected (K, in_dim) with K >= 2")
        check_finite_tensor("weight", w)
        k = w.shape[0]
        mech = cls(w.shape[1], k, seed=0)
        b = _vector(bias, k, "bias", allow_scalar=True)
        if k == 2:  # stored as one logit: l_1 - l_0
            mech._set_affine((w[1] - w[0]).reshape(1, -1), (b[1] - b[0]).reshape(1))
        else:
            mech._set_affine(w, b)
        return mech
