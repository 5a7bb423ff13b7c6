"""Pyro Messengers, one effect each, that the causal queries compose.

* :class:`Intervene`   -- do(X := v) or do(X := g(x)): replaces a site's mechanism.
* :class:`AbductNoise` -- records standardised residuals eps = (x - loc) / scale (Eq. 4.43).
* :class:`ReplayNoise` -- sets x = loc + scale * eps from given residuals (Eq. 4.39).
* :class:`MeasurementScale` -- per-unit sigma on measurement sites o_obs ~ Normal(o, sigma_t).

Applied to a :class:`models.WorldModel` or a :class:`inference.program.Program`, each returns a
``Program`` that keeps the model's graph, so the queries accept it; entered with ``with``
they act on every query run inside.

Discrete sites (:class:`models.discrete.CategoricalCode`) follow the Gumbel-max SCM: abduction
draws ``(..., N, K)`` standard Gumbel noise from its exact posterior given the observed
category (:func:`models.discrete.gumbel_posterior`, from the handler's generator), and replay
sets ``x = argmax_k (l_k + g_k)``; zero noise replays the mode.

They work on any Pyro program whose sites are location-scale distributions written the
natural way (``Normal(f(pa), sigma)``, optionally ``.to_event``/expanded), ``Uniform``
and ``Delta``; no ``TransformedDistribution`` is needed. The scale may differ per unit, as
for heteroscedastic and ensemble sites (``Normal(f(pa), sigma(pa))``): abduction divides by
the scale at the factual parents, replay multiplies by the scale at the parents it sees. Compose them as
``Intervene(ReplayNoise(model))``: the inner handler fixes the natural value first and
the outer one intervenes on it, so shift interventions see the abducted value.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import pyro.distributions as dist
import torch
from pyro.poutine.messenger import Messenger
from pyro.poutine.runtime import Message
from pyro.poutine.subsample_messenger import _Subsample
from torch import Tensor

from inference.active import register, unregister
from inference.program import Program, as_program
from models.checks import (
    as_float_tensor,
    check_choice,
    check_finite_tensor,
    check_generator,
    check_mapping,
    describe,
)
from models.discrete import CategoricalCode, check_codes, gumbel_max, gumbel_posterior
from models.world import WorldModel

__all__ = [
    "AbductNoise",
    "Intervene",
    "InterventionSpec",
    "MeasurementScale",
    "ProgramMessenger",
    "ReplayNoise",
    "is_variable_site",
    "location_scale",
]

InterventionSpec = float | Tensor | Callable[[Tensor], Tensor]

_LOC_SCALE = (dist.Normal, dist.Laplace, dist.Cauchy, dist.StudentT)


def is_variable_site(msg: Message) -> bool:
    """True for ``pyro.sample`` statements of the program (not plate subsampling)."""
    return msg["type"] == "sample" and not isinstance(msg["fn"], _Subsample)


def site_shape(fn: dist.Distribution) -> torch.Size:
    return fn.batch_shape + fn.event_shape


def _base(fn: dist.Distribution) -> dist.Distribution:
    while isinstance(fn, torch.distributions.Independent):
        fn = fn.base_dist
    return fn


def location_scale(fn: dist.Distribution, name: str) -> tuple[Tensor, Tensor]:
    """``(loc, scale)`` with ``x = loc + scale * eps``, both broadcast to the site shape.

    Normal, Laplace, Cauchy and StudentT use their loc and scale (eps in standard
    units); Uniform uses ``low`` and ``high - low`` (eps in [0, 1)); Delta has scale 0.

    Raises:
        NotImplementedError: for any other family, naming the site.
    """
    shape = site_shape(fn)
    base = _base(fn)
    if isinstance(base, _LOC_SCALE):
        loc, scale = base.loc, base.scale
    elif isinstance(base, dist.Uniform):
        loc, scale = base.low, base.high - base.low
    elif isinstance(base, dist.Delta):
        loc, scale = base.v, torch.zeros_like(base.v)
    else:
        raise NotImplementedError(
            f"site {name!r} has a {type(base).__name__} distribution; abduction and noise replay "
            "support the symmetric location-scale families (Normal, Laplace, Cauchy, StudentT), Uniform and Delta"
        )
    return loc.expand(shape), scale.expand(shape)


class ProgramMessenger(Messenger):
    """A pal handler: applied to a world model or a program it returns a :class:`Program`.

    Subclasses name the sites they act on in :meth:`site_names`; applying the handler to a
    program whose graph lacks one of them raises.
    """

    def site_names(self) -> tuple[str, ...]:
        """The sites this handler acts on (empty: every site)."""
        return ()

    def __enter__(self) -> Any:
        """Enter Pyro's handler stack and pal's registry (:mod:`inference.active`)."""
        out = super().__enter__()
        register(self)
        return out

    def __exit__(self, *args: Any) -> None:
        """Leave Pyro's handler stack and pal's registry."""
        try:
            super().__exit__(*args)
        finally:
            unregister(self)

    def __call__(self, fn: Any) -> Any:
        """``fn`` under this handler: a :class:`Program` for a model or program, else Pyro's wrapper."""
        if isinstance(fn, (WorldModel, Program)):
            program = as_program(fn)
            unknown = sorted(n for n in self.site_names() if n not in program.graph)
            if unknown:
                raise ValueError(
                    f"{type(self).__name__} names {unknown}, which are not sites of the program; "
                    f"its sites: {list(program.graph.names)}"
                )
            return program.with_handler(self)
        return super().__call__(fn)


def _outer_broadcast(eps: torch.Size, site: torch.Size) -> torch.Size | None:
    """The common shape of noise and site when they differ only by leading (plate) dims; else None."""
    k = min(len(eps), len(site))
    if eps[len(eps) - k :] != site[len(site) - k :]:
        return None
    return eps if len(eps) >= len(site) else site


def _fix(msg: Message, value: Tensor, flag: str) -> None:
    """Make the site deterministic at ``value``: Delta with zero log-density, not a latent."""
    fn = msg["fn"]
    msg["value"] = value
    msg["fn"] = dist.Delta(value, event_dim=fn.event_dim)
    msg["is_observed"] = True
    msg["infer"] = {**msg["infer"], flag: True, "pal_fn": msg["infer"].get("pal_fn", fn)}


def broadcast_intervention(value: Any, shape: torch.Size, name: str) -> Tensor:
    """Broadcast a hard intervention value to the site shape ``(..., N, dim)``.

    Accepted: a scalar when dim is 1, a ``(dim,)`` vector (same for every unit), exactly
    the trailing shape ``(N, dim)``, or ``(..., N, dim)`` with the leading dims of enclosing
    plates. Anything else raises.
    """
    v = value if isinstance(value, Tensor) else as_float_tensor(value, f"intervention on {name!r}")
    dim = shape[-1]
    if v.ndim > len(shape) and v.shape[v.ndim - len(shape) :] == shape:
        # leading dims of outer plates (candidates, draws) that broadcast the site later
        if not torch.isfinite(v).all():
            raise ValueError(f"intervention on {name!r} contains NaN or inf")
        return v
    if v.ndim == 0:
        ok = dim == 1
    elif v.ndim == 1:
        ok = v.shape[0] == dim
    else:
        ok = v.ndim <= len(shape) and v.shape == shape[len(shape) - v.ndim :]
    if not ok:
        raise ValueError(
            f"intervention on {name!r} has shape {tuple(v.shape)}, expected a scalar (dim 1), "
            f"({dim},) or {tuple(shape[-2:])}"
        )
    if not torch.isfinite(v).all():
        raise ValueError(f"intervention on {name!r} contains NaN or inf")
    return v.expand(shape)


class Intervene(ProgramMessenger):
    """do(): replace the mechanism of each named site by an assignment.

    A hard value ``v`` sets ``X := v``; a callable ``g`` sets ``X := g(x)`` where ``x`` is the
    value the site takes without the intervention (observed, replayed, or sampled from its
    mechanism). The intervened site becomes a ``Delta`` with zero log-density, so it carries
    no evidence about its parents, and children see the new value.

    Args:
        interventions: site name -> value or callable.
        bounds: optional site name -> ``(low, high)`` tensors; values a callable produces
            for these sites must lie within them (:func:`inference.do` passes the action
            bounds). Hard values are checked by :func:`inference.do` before the run.
    """

    def __init__(
        self,
        interventions: Mapping[str, InterventionSpec],
        bounds: Mapping[str, tuple[Tensor, Tensor]] | None = None,
    ) -> None:
        super().__init__()
        interventions = check_mapping("interventions", interventions)
        for name in interventions:
            if not isinstance(name, str):
                raise ValueError(f"intervention targets must be site names (str), got {describe(name)}")
        self.interventions = dict(interventions)
        self.bounds = dict(check_mapping("bounds", bounds, allow_none=True))

    def site_names(self) -> tuple[str, ...]:
        """The intervened sites."""
        return tuple(self.interventions)

    def _pyro_sample(self, msg: Message) -> None:
        name = msg["name"]
        if name not in self.interventions or not is_variable_site(msg):
            return
        spec = self.interventions[name]
        fn = msg["fn"]
        shape = site_shape(fn)
        if callable(spec):
            natural = msg["value"] if msg["value"] is not None else fn()
            value = spec(natural)
            if not isinstance(value, Tensor) or value.shape != natural.shape:
                got = tuple(value.shape) if isinstance(value, Tensor) else type(value).__name__
                raise ValueError(
                    f"shift intervention on {name!r} returned {got}, expected a tensor of shape {tuple(natural.shape)}"
                )
            if not torch.isfinite(value).all():
                raise ValueError(f"shift intervention on {name!r} produced NaN or inf")
            if name in self.bounds:
                low, high = self.bounds[name]
                tol = 4 * torch.finfo(torch.float32).eps * torch.maximum(low.abs(), high.abs()).clamp_min(1.0)
                v = value.detach()
                if bool(((v < low - tol) | (v > high + tol)).any()):
                    raise ValueError(
                        f"shift intervention on {name!r} produced values outside its bounds "
                        f"[{low.tolist()}, {high.tolist()}] (range {float(v.min()):g} .. {float(v.max()):g})"
                    )
        else:
            value = broadcast_intervention(spec, shape, name)
        base = _base(fn)
        if isinstance(base, CategoricalCode):
            check_codes(f"intervention on {name!r}", value, base.categories)
        _fix(msg, value, "pal_intervened")


class AbductNoise(ProgramMessenger):
    """Abduction: record ``eps = (x - loc) / scale`` at every location-scale site.

    After the program runs, :attr:`noise` maps site name -> eps with the site's shape.
    Intervened and Delta sites get eps = 0. A discrete site gets ``(..., N, K)`` Gumbel
    noise drawn from its posterior given the observed category (module docstring).

    Args:
        generator: source of the Gumbel posterior draws (None: torch's global RNG).
    """

    def __init__(self, generator: torch.Generator | None = None) -> None:
        super().__init__()
        self.generator = check_generator("generator", generator)
        self.noise: dict[str, Tensor] = {}

    def _pyro_post_sample(self, msg: Message) -> None:
        if not is_variable_site(msg):
            return
        base = _base(msg["fn"])
        if isinstance(base, CategoricalCode):
            self.noise[msg["name"]] = gumbel_posterior(base.logits, msg["value"], self.generator)
            return
        loc, scale = location_scale(msg["fn"], msg["name"])
        safe = torch.where(scale > 0, scale, torch.ones_like(scale))
        self.noise[msg["name"]] = torch.where(scale > 0, (msg["value"] - loc) / safe, torch.zeros_like(loc))


class ReplayNoise(ProgramMessenger):
    """Set every unobserved site to ``loc + scale * eps`` from given residuals.

    Args:
        noise: site name -> eps, shaped like the site; missing sites use ``default``.
        default: ``"expected"`` (eps = 0, the mean for symmetric families, Alg. 4.2's
            u-bar) or ``"error"`` (every site must have a residual).

    Observed sites keep their observed values (Alg. 4.1, line 7).
    """

    def __init__(self, noise: Mapping[str, Tensor] | None = None, default: str = "error") -> None:
        super().__init__()
        self.default = check_choice("default", default, ("expected", "error"))
        self.noise = {}
        for name, eps in check_mapping("noise", noise, allow_none=True).items():
            if not isinstance(name, str):
                raise ValueError(f"noise keys must be site names (str), got {describe(name)}")
            keep = eps.dtype if isinstance(eps, Tensor) and eps.is_floating_point() else None
            t = as_float_tensor(eps, f"noise[{name!r}]", keep)
            self.noise[name] = check_finite_tensor(f"noise[{name!r}]", t)

    def site_names(self) -> tuple[str, ...]:
        """The sites with replayed noise."""
        return tuple(self.noise)

    def _pyro_sample(self, msg: Message) -> None:
        if not is_variable_site(msg) or msg["is_observed"]:
            return
        name = msg["name"]
        base = _base(msg["fn"])
        if isinstance(base, CategoricalCode):
            self._replay_discrete(msg, base)
            return
        loc, scale = location_scale(msg["fn"], name)
        if name in self.noise:
            eps = self.noise[name].to(loc.dtype)
            if eps.shape != loc.shape:
                # outer plates (draws, scenarios) broadcast the site after this handler ran
                shape = _outer_broadcast(eps.shape, loc.shape)
                if shape is None:
                    raise ValueError(
                        f"replayed noise for {name!r} has shape {tuple(eps.shape)}, expected {tuple(loc.shape)}"
                    )
                loc, scale, eps = loc.expand(shape), scale.expand(shape), eps.expand(shape)
        elif self.default == "expected":
            # the mean: eps = 0 for the symmetric families, 1/2 for Uniform(low, high)
            eps = torch.full_like(loc, 0.5 if isinstance(_base(msg["fn"]), dist.Uniform) else 0.0)
        else:
            raise ValueError(f"no replayed noise for site {name!r}; abduct it or pass default='expected'")
        _fix(msg, loc + scale * eps, "pal_replayed")
        msg["infer"]["pal_eps"] = eps

    def _replay_discrete(self, msg: Message, base: CategoricalCode) -> None:
        name, logits = msg["name"], base.logits
        if name in self.noise:
            eps = self.noise[name].to(logits.dtype)
            if eps.shape != logits.shape:
                shape = _outer_broadcast(eps.shape, logits.shape)
                if shape is None:
                    raise ValueError(
                        f"replayed Gumbel noise for the discrete site {name!r} has shape {tuple(eps.shape)}, "
                        f"expected {tuple(logits.shape)} (units, categories)"
                    )
                logits, eps = logits.expand(shape), eps.expand(shape)
        elif self.default == "expected":
            eps = torch.zeros_like(logits)  # zero Gumbel noise: the mode
        else:
            raise ValueError(f"no replayed noise for site {name!r}; abduct it or pass default='expected'")
        _fix(msg, gumbel_max(logits, eps), "pal_replayed")


class MeasurementScale(ProgramMessenger):
    """Set a per-unit scale on Normal measurement sites: ``o_obs ~ Normal(o, sigma_t)``.

    Perception reports a different uncertainty for every frame (from its pose
    diagnostics); the model's learned sigma of a measurement site is replaced by it.

    Args:
        scales: site name -> sigma, ``(dim,)`` or ``(N, dim)``, finite and > 0, in the
            site's units (tensors or float arrays).
    """

    def __init__(self, scales: Mapping[str, Tensor]) -> None:
        super().__init__()
        self.scales: dict[str, Tensor] = {}
        for name, raw in check_mapping("scales", scales).items():
            if not isinstance(name, str):
                raise ValueError(f"measurement scale keys must be site names (str), got {describe(name)}")
            s = as_float_tensor(raw, f"measurement scale of {name!r}")
            if s.ndim not in (1, 2):
                raise ValueError(
                    f"measurement scale of {name!r} has shape {tuple(s.shape)}, expected (dim,) or (N, dim)"
                )
            if not (torch.isfinite(s).all() and (s > 0).all()):
                raise ValueError(f"measurement scale of {name!r} must be finite and > 0, got {describe(s)}")
            self.scales[name] = s

    def site_names(self) -> tuple[str, ...]:
        """The measurement sites."""
        return tuple(self.scales)

    def _pyro_sample(self, msg: Message) -> None:
        name = msg["name"]
        if name not in self.scales or not is_variable_site(msg):
            return
        infer = msg["infer"] or {}
        if infer.get("pal_replayed") and "pal_eps" in infer:
            # replayed by an inner ReplayNoise before this handler saw the site: replay with
            # the measurement scale, so the order of the handlers does not matter
            fn = infer["pal_fn"]
            base = _base(fn)
            loc = base.loc.expand(site_shape(fn))
            scale = self._scale_for(name, site_shape(fn))
            value = loc + scale.expand_as(loc) * infer["pal_eps"]
            _fix(msg, value, "pal_replayed")
            return
        base = _base(msg["fn"])
        if not isinstance(base, dist.Normal):
            raise ValueError(f"measurement site {name!r} must be Normal, got {type(base).__name__}")
        shape = site_shape(msg["fn"])
        scale = self._scale_for(name, shape)
        event_dims = len(msg["fn"].event_shape)
        msg["fn"] = dist.Normal(base.loc.expand(shape), scale.expand(shape)).to_event(event_dims)

    def _scale_for(self, name: str, shape: torch.Size) -> Tensor:
        scale = self.scales[name]
        # trailing (N, dim) or (dim,); outer dims (e.g. vectorised particles) are broadcast
        if scale.shape != shape[-scale.ndim :]:
            raise ValueError(
                f"measurement scale of {name!r} has shape {tuple(scale.shape)}, expected "
                f"{tuple(shape[-1:])} or {tuple(shape[-2:])}"
            )
        return scale
