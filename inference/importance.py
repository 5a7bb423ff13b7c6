"""Self-normalised importance sampling of state posteriors, with the prior as proposal.

For every unit n, P particles ``z_p ~ p(z | do(...))`` are drawn by running the program
with the evidence (latent sites sample from their mechanisms given their parents), and

    log w_pn = sum_{observed sites i} log p(x_i,n | pa_i(z_p)),     w_pn <- w_pn / sum_p w_pn.

The posterior mean and sd are the weighted moments; ``num_samples`` draws per unit are
resampled (multinomial, with replacement) from the particles. Every mode the prior reaches
is kept in proportion to its posterior mass. The estimate is consistent as P grows; its
quality per unit is the effective sample size and the PSIS Pareto-k of the weights
(:mod:`inference.diagnostics`). Discrete latent sites are sampled like the others.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import pyro
import torch
from pyro import poutine
from torch import Tensor

from inference.diagnostics import from_weights
from inference.program import SiteRoles, log_joint
from inference.svi_state import Fitted
from models.checks import check_int

__all__ = ["ImportanceOptions", "importance_posterior", "weighted_moments"]


@dataclass(frozen=True)
class ImportanceOptions:
    """Sizes of importance sampling.

    Attributes:
        num_particles: prior particles P per unit, >= 10.
        chunk: particles x units per program run (memory bound), >= 1.
    """

    num_particles: int = 10_000
    chunk: int = 2_000_000

    def __post_init__(self) -> None:
        check_int("num_particles", self.num_particles, minimum=10)
        check_int("chunk", self.chunk, minimum=1)

    def to_dict(self) -> dict[str, Any]:
        """JSON-compatible fields."""
        return dict(self.__dict__)


def weighted_moments(values: Tensor, weights: Tensor) -> tuple[Tensor, Tensor]:
    """Mean and sd of ``(P, N, dim)`` values under ``(P, N)`` normalised weights: two ``(N, dim)``."""
    w = weights[..., None]
    mean = (w * values).sum(0)
    var = (w * (values - mean) ** 2).sum(0)
    return mean, var.clamp_min(0).sqrt()


def resample(
    values: Mapping[str, Tensor], weights: Tensor, num_samples: int, generator: torch.Generator
) -> dict[str, Tensor]:
    """``num_samples`` draws per unit: name -> ``(S, N, dim)`` from ``(P, N, dim)`` particles."""
    n = weights.shape[1]
    idx = torch.multinomial(
        weights.T.double(), num_samples, replacement=True, generator=generator
    ).T  # (S, N)
    units = torch.arange(n).expand_as(idx)
    return {k: v[idx, units] for k, v in values.items()}


def importance_posterior(
    program: Callable[..., Any],
    evidence: Mapping[str, Tensor],
    n: int,
    sites: SiteRoles,
    num_samples: int,
    options: ImportanceOptions,
    generator: torch.Generator,
) -> Fitted:
    """Importance-sample the latent sites of every unit (module docstring).

    Args:
        program: the program.
        evidence: name -> ``(N, dim)`` observed values.
        n: units N.
        sites: the sites of the program's trace.
        num_samples: resampled draws S per unit.
        options: particle count and chunk size.
        generator: source of the resampling (the particles use torch's RNG, seeded by the caller).

    Returns:
        :class:`inference.svi_state.Fitted` (no losses).
    """
    p_total = options.num_particles
    per_run = max(1, min(p_total, options.chunk // max(n, 1)))
    values: dict[str, list[Tensor]] = {k: [] for k in sites.latent}
    log_w: list[Tensor] = []
    done = 0
    with torch.no_grad(), pyro.validation_enabled(False):
        while done < p_total:
            p = min(per_run, p_total - done)
            with pyro.plate("_particles", p, dim=-2):
                trace = poutine.trace(program).get_trace(evidence, n)
            lw = log_joint(trace, set(sites.latent))
            log_w.append(torch.as_tensor(lw).expand(p, n) if isinstance(lw, Tensor) else torch.zeros(p, n))
            for k in sites.latent:
                values[k].append(trace.nodes[k]["value"].expand(p, n, sites.dims[k]))
            done += p
    lw_all = torch.cat(log_w)
    particles = {k: torch.cat(v) for k, v in values.items()}
    weights = torch.softmax(lw_all.double(), 0).to(lw_all.dtype)
    mean, sd = {}, {}
    for k, v in particles.items():
        mean[k], sd[k] = weighted_moments(v, weights)
    samples = resample(particles, weights, num_samples, generator)
    diag = from_weights("importance", lw_all, "the prior (as proposal)")
    return Fitted(samples, mean, sd, (), diag)
