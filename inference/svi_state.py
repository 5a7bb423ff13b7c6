"""Variational state posteriors (thesis Eq. 4.41-4.42) with Pyro autoguides.

    q* = argmin_q  E_q[ log q(z) - log p_M(x_obs, z) ]

over the continuous latent sites z, with ClippedAdam and a geometric learning-rate decay from
``lr`` to ``lr_final``. The guides:

* ``"normal"``: ``AutoNormal``, mean field, one Normal per unit and component;
* ``"mvn"``: ``AutoMultivariateNormal``, one full-rank Gaussian over every latent component
  of every unit;
* ``"flow"``: a normalizing flow ``z = loc + scale * s(u)``, ``u ~ N(0, I)``, with ``s`` an
  element-wise monotone rational-quadratic spline (Durkan et al. 2019) of ``bins`` bins on
  ``[-bound, bound]`` (the identity outside): every unit and component gets its own flexible
  1-d marginal, which can hold several modes.

Discrete latent sites are summed out exactly in the ELBO (``TraceEnum_ELBO``, parallel
enumeration); their posterior draws come from :func:`inference.enumeration.sample_discrete`
given each draw of z, so a draw is ``z ~ q(z)``, ``d ~ p(d | z, x_obs)``.

The fit diagnostic is the PSIS Pareto-k of the guide as an importance proposal for each
unit's posterior (:mod:`inference.diagnostics`), from the guide's marginal of that unit.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import pyro
import pyro.distributions as dist
import torch
from pyro import poutine
from pyro.distributions.torch_transform import TransformModule
from pyro.infer import SVI, Trace_ELBO, TraceEnum_ELBO, config_enumerate
from pyro.infer.autoguide import AutoMultivariateNormal, AutoNormal, AutoNormalizingFlow
from pyro.optim import ClippedAdam
from torch import Tensor, nn
from tqdm import tqdm

from inference.diagnostics import Diagnostics, from_weights
from inference.enumeration import sample_discrete
from inference.program import SiteRoles, log_joint
from models.checks import check_float, check_int

__all__ = ["SVI_GUIDES", "SVIOptions", "svi_posterior"]

SVI_GUIDES = ("normal", "mvn", "flow")

_Z1 = 0.8413447460685429  # Phi(1): (q(Phi(1)) - q(Phi(-1))) / 2 is the sd of a Normal marginal
_DIAGNOSTIC_DRAWS = 1000


@dataclass(frozen=True)
class SVIOptions:
    """Optimiser and guide settings of the variational posteriors.

    Attributes:
        lr: initial ClippedAdam learning rate, > 0.
        lr_final: learning rate at the last step (geometric decay), > 0.
        num_particles: vectorised ELBO particles per step, >= 1.
        init_scale: initial scale of the Gaussian guides, > 0 (the flow starts at the
            prior's scale).
        bins: spline bins of the ``"flow"`` guide, >= 2.
        bound: the flow's spline acts on ``[-bound, bound]`` (standardised units), > 0.
    """

    lr: float = 0.1
    lr_final: float = 0.001
    num_particles: int = 16
    init_scale: float = 0.1
    bins: int = 16
    bound: float = 4.0

    def __post_init__(self) -> None:
        check_float("lr", self.lr, minimum=0.0, min_open=True)
        check_float("lr_final", self.lr_final, minimum=0.0, min_open=True)
        check_int("num_particles", self.num_particles, minimum=1)
        check_float("init_scale", self.init_scale, minimum=0.0, min_open=True)
        check_int("bins", self.bins, minimum=2)
        check_float("bound", self.bound, minimum=0.0, min_open=True)

    def to_dict(self) -> dict[str, Any]:
        """JSON-compatible fields."""
        return dict(self.__dict__)


class _Affine(TransformModule):
    """Element-wise ``y = loc + exp(log_scale) * x`` with learned ``(L,)`` loc and log-scale."""

    domain = dist.constraints.real
    codomain = dist.constraints.real
    bijective = True

    def __init__(self, loc: Tensor, scale: Tensor) -> None:
        super().__init__(cache_size=1)
        self.loc = nn.Parameter(loc.detach().clone())
        self.log_scale = nn.Parameter(scale.detach().clamp_min(1e-3).log())

    def _call(self, x: Tensor) -> Tensor:
        return self.loc + self.log_scale.exp() * x

    def _inverse(self, y: Tensor) -> Tensor:
        return (y - self.loc) * torch.exp(-self.log_scale)

    def log_abs_det_jacobian(self, x: Tensor, y: Tensor) -> Tensor:
        return self.log_scale.expand(x.shape)


def _flow(options: SVIOptions, loc: Tensor, scale: Tensor) -> Callable[[int], Any]:
    def make(latent_dim: int) -> Any:
        spline = dist.transforms.Spline(latent_dim, count_bins=options.bins, bound=options.bound)
        return dist.transforms.ComposeTransformModule([spline, _Affine(loc, scale)])

    return make


@dataclass
class Fitted:
    """What a posterior method hands back to :func:`inference.infer_state`."""

    samples: dict[str, Tensor]
    mean: dict[str, Tensor]
    sd: dict[str, Tensor]
    losses: tuple[float, ...]
    diagnostics: Diagnostics
    autoguide: Any = None


def _prior_scale(
    program: Callable[..., Any], evidence: Mapping[str, Tensor], n: int, names: tuple[str, ...]
) -> tuple[dict[str, Tensor], dict[str, Tensor]]:
    """Per-unit prior mean and sd of the latent sites from 256 draws (to place the flow)."""
    with torch.no_grad(), pyro.validation_enabled(False), pyro.plate("_pilot", 256, dim=-2):
        trace = poutine.trace(program).get_trace(evidence, n)
    mean = {k: trace.nodes[k]["value"].mean(0) for k in names}
    sd = {k: trace.nodes[k]["value"].std(0).clamp_min(1e-3) for k in names}
    return mean, sd


def svi_posterior(
    program: Callable[..., Any],
    evidence: Mapping[str, Tensor],
    n: int,
    sites: SiteRoles,
    guide: str,
    num_steps: int,
    num_samples: int,
    options: SVIOptions,
    progress_bar: bool,
    generator: torch.Generator,
) -> Fitted:
    """Fit the guide by SVI and draw ``num_samples`` posterior samples per unit.

    Args:
        program: the program (evidence passed as ``data``).
        evidence: name -> ``(N, dim)`` observed values.
        n: units N.
        sites: the sites of the program's trace.
        guide: one of :data:`SVI_GUIDES`.
        num_steps: SVI steps.
        num_samples: posterior draws S.
        options: optimiser and guide settings.
        progress_bar: show a tqdm bar.
        generator: source of the draws of the discrete latents (the guide samples with
            torch's RNG, seeded by the caller).

    Returns:
        :class:`Fitted` with samples ``(S, N, dim)``.
    """
    continuous = sites.continuous
    discrete = tuple(sites.discrete)
    model = config_enumerate(program, "parallel") if discrete else program
    blocked = poutine.block(program, hide=list(discrete)) if discrete else program
    if not continuous:
        auto = None
    elif guide == "normal":
        auto = AutoNormal(blocked, init_scale=options.init_scale)
    elif guide == "mvn":
        auto = AutoMultivariateNormal(blocked, init_scale=options.init_scale)
    else:
        mean, sd = _prior_scale(program, evidence, n, continuous)
        loc = torch.cat([mean[k].reshape(-1) for k in continuous])
        scale = torch.cat([sd[k].reshape(-1) for k in continuous])
        auto = AutoNormalizingFlow(blocked, _flow(options, loc, scale / options.bound * 2))
    losses: list[float] = []
    if auto is not None:
        optim = ClippedAdam({"lr": options.lr, "lrd": (options.lr_final / options.lr) ** (1.0 / num_steps)})
        kw = {"num_particles": options.num_particles, "vectorize_particles": options.num_particles > 1}
        elbo = (
            TraceEnum_ELBO(max_plate_nesting=1, **kw) if discrete else Trace_ELBO(max_plate_nesting=1, **kw)
        )
        svi = SVI(model, auto, optim, elbo)
        bar = tqdm(range(num_steps), desc="infer_state", disable=not progress_bar, leave=False)
        for _ in bar:
            loss = svi.step(evidence, n) / n
            if not math.isfinite(loss):
                raise FloatingPointError(
                    f"ELBO became {loss} at step {len(losses)}; check that the evidence lies in the "
                    "support of the model (e.g. within action bounds) or lower lr"
                )
            losses.append(loss)
            if len(losses) % 50 == 0:
                bar.set_postfix(loss=f"{loss:.4g}")
    with torch.no_grad():
        samples = _draw(program, auto, evidence, n, sites, num_samples, generator)
        mean, sd = _moments(auto, evidence, n, continuous, samples)
        diag = _diagnose(program, auto, evidence, n, sites, guide)
    return Fitted(samples, mean, sd, tuple(losses), diag, auto)


def _draw(
    program: Callable[..., Any],
    auto: Any,
    evidence: Mapping[str, Tensor],
    n: int,
    sites: SiteRoles,
    num_samples: int,
    generator: torch.Generator,
) -> dict[str, Tensor]:
    """``(S, N, dim)`` draws: z from the guide, then the discrete latents from ``p(d | z, x_obs)``."""
    out: dict[str, Tensor] = {}
    if auto is not None:
        with pyro.validation_enabled(False), pyro.plate("_posterior_samples", num_samples, dim=-2):
            guide_trace = poutine.trace(auto).get_trace(evidence, n)
        for k in sites.continuous:
            v = guide_trace.nodes[k]["value"].detach()
            out[k] = v.expand(num_samples, n, sites.dims[k]).clone()
    if sites.discrete:
        if not out:  # only discrete latents: p(d | x_obs) is the same for every draw
            drawn = sample_discrete(program, evidence, {}, n, sites, generator, num_samples)
        else:
            drawn = sample_discrete(program, evidence, out, n, sites, generator)
        out.update(drawn)
    return {k: out[k] for k in sites.latent}


def _moments(
    auto: Any,
    evidence: Mapping[str, Tensor],
    n: int,
    continuous: tuple[str, ...],
    samples: Mapping[str, Tensor],
) -> tuple[dict[str, Tensor], dict[str, Tensor]]:
    """Mean and sd: the guide's median and quantile half-width for AutoNormal on real sites, else Monte Carlo."""
    mean = {k: v.mean(0) for k, v in samples.items()}
    sd = {k: v.std(0) for k, v in samples.items()}
    if isinstance(auto, AutoNormal):
        median = auto.median(evidence, n)
        quant = auto.quantiles([1 - _Z1, _Z1], evidence, n)
        for k in continuous:
            if _support_is_real(auto.prototype_trace.nodes[k]["fn"].support):
                mean[k] = median[k].detach()
                lo, hi = quant[k].detach()
                sd[k] = (hi - lo) / 2
    return mean, sd


def _support_is_real(support: Any) -> bool:
    base = support
    while hasattr(base, "base_constraint"):
        base = base.base_constraint
    return base is dist.constraints.real


def _offsets(continuous: tuple[str, ...], n: int, dims: Mapping[str, int]) -> dict[str, Tensor]:
    """Site -> ``(N, dim)`` positions of its unit blocks in a joint guide's latent vector."""
    out, start = {}, 0
    for k in continuous:
        out[k] = start + torch.arange(n)[:, None] * dims[k] + torch.arange(dims[k])
        start += n * dims[k]
    return out


def _log_q_at(
    auto: Any, values: Mapping[str, Tensor], continuous: tuple[str, ...], n: int, dims: Mapping[str, int]
) -> Tensor:
    """``(P, N)`` log-density of each unit's marginal under the guide at ``(P, N, dim)`` values."""
    if isinstance(auto, AutoNormal):
        total: Tensor | float = 0.0
        for k in continuous:
            loc, scale = auto._get_loc_and_scale(k)
            total = total + dist.Normal(loc, scale).log_prob(values[k]).sum(-1)
        return total  # type: ignore[return-value]
    offsets = _offsets(continuous, n, dims)
    idx = torch.cat([offsets[k] for k in continuous], -1)  # (N, d)
    v = torch.cat([values[k].expand(-1, n, dims[k]) for k in continuous], -1)  # (P, N, d)
    if isinstance(auto, AutoMultivariateNormal):
        lower = auto.scale[:, None] * auto.scale_tril
        cov = lower @ lower.T
        marginal = dist.MultivariateNormal(
            auto.loc[idx], covariance_matrix=cov[idx[:, :, None], idx[:, None, :]]
        )
        return marginal.log_prob(v)
    # the element-wise flow: log q = log N(u) - sum of element-wise log-Jacobians
    y = torch.zeros(v.shape[0], auto.latent_dim, dtype=v.dtype)
    y[:, idx.reshape(-1)] = v.reshape(v.shape[0], -1)
    ladj = torch.zeros_like(y)
    for t in reversed(list(auto.transform.parts)):
        x = t.inv(y)
        ladj = ladj + t.log_abs_det_jacobian(x, y)
        y = x
    per_element = dist.Normal(0.0, 1.0).log_prob(y) - ladj
    return per_element[:, idx].sum(-1)


#: Prior particles per unit of the missed-mass check, and its thresholds.
_CHECK_PARTICLES = 2000
MISSED_MASS_THRESHOLD = 0.05
_TAIL = 1e-3


def _diagnose(
    program: Callable[..., Any],
    auto: Any,
    evidence: Mapping[str, Tensor],
    n: int,
    sites: SiteRoles,
    guide: str,
) -> Diagnostics:
    """PSIS Pareto-k of the guide for each unit (module docstring)."""
    name = f"svi:{guide}"
    if auto is None:
        return Diagnostics(name, message=f"{name}: no continuous latent site; discrete ones are exact")
    if sites.discrete:
        return Diagnostics(
            name,
            message=f"{name}: discrete latents are summed exactly; no Pareto-k for the mixed guide",
        )
    with pyro.validation_enabled(False), pyro.plate("_diagnostic", _DIAGNOSTIC_DRAWS, dim=-2):
        guide_trace = poutine.trace(auto).get_trace(evidence, n)
        model_trace = poutine.trace(poutine.replay(program, guide_trace)).get_trace(evidence, n)
    continuous, dims = sites.continuous, sites.dims
    draws = {k: guide_trace.nodes[k]["value"].expand(_DIAGNOSTIC_DRAWS, n, dims[k]) for k in continuous}
    log_q = _log_q_at(auto, draws, continuous, n, dims)
    log_p = log_joint(model_trace, set())
    diag = from_weights(name, (log_p - log_q).reshape(_DIAGNOSTIC_DRAWS, n), f"the {guide} guide")
    # Importance weights of the guide cannot see a mode it misses: check the posterior mass
    # (by prior importance sampling) that lies where q has almost no density.
    with pyro.validation_enabled(False), pyro.plate("_check", _CHECK_PARTICLES, dim=-2):
        prior_trace = poutine.trace(program).get_trace(evidence, n)
    lw = log_joint(prior_trace, set(sites.latent))
    weights = torch.softmax(lw.expand(_CHECK_PARTICLES, n).double(), 0).to(log_q.dtype)
    particles = {k: prior_trace.nodes[k]["value"].expand(_CHECK_PARTICLES, n, dims[k]) for k in continuous}
    threshold = torch.quantile(log_q, _TAIL, dim=0)  # (N,): q's 0.1 % density level
    missed = (weights * (_log_q_at(auto, particles, continuous, n, dims) < threshold)).sum(0)
    bad = torch.nonzero(missed > MISSED_MASS_THRESHOLD).flatten().tolist()
    flagged = tuple(sorted(set(diag.flagged) | set(bad)))
    message = diag.message
    if bad:
        message = (
            f"{name}: on {len(bad)} of {n} units more than {MISSED_MASS_THRESHOLD:g} of the posterior mass "
            f"(worst {float(missed.max()):.2f}) lies where the guide has almost no density, e.g. a second "
            "mode; try guide='grid' (low-dimensional latents), 'importance' or 'flow'"
        ) + ("" if diag.ok else f"; and {diag.message}")
    return Diagnostics(
        name,
        pareto_k=diag.pareto_k,
        ess=diag.ess,
        flagged=flagged,
        message=message,
        extra={"missed_mass_max": float(missed.max()), "missed_mass": missed.tolist() if n <= 50 else None},
    )
