"""Exact sums over the discrete latent sites of a program.

With discrete latent sites ``d = (d_1 .. d_J)`` of ``K_1 .. K_J`` categories, every
combination ``c`` of codes (``C = prod_j K_j`` of them) is run through the program, and

    p(d = c | z, x_obs) = exp(log p(x_obs, z, c)) / sum_c' exp(log p(x_obs, z, c')),

given draws z of the continuous latents. :func:`sample_discrete` draws d from it with the
Gumbel-max trick from a local generator, which is how the variational posteriors of
:mod:`inference.svi_state` complete their draws (``z ~ q(z)``, then ``d ~ p(d | z, x_obs)``).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Mapping
from typing import Any

import pyro
import torch
from pyro import poutine
from torch import Tensor

from inference.program import SiteRoles, log_joint
from models.discrete import gumbel

__all__ = ["MAX_COMBINATIONS", "code_combinations", "sample_discrete"]

#: The most combinations of discrete latent codes that are enumerated.
MAX_COMBINATIONS = 4096


def code_combinations(sites: SiteRoles, limit: int = MAX_COMBINATIONS) -> list[tuple[int, ...]]:
    """Every combination of codes of the discrete latent sites (in ``sites.discrete`` order).

    Raises:
        ValueError: more than ``limit`` combinations, naming the sites and their K.
    """
    total = math.prod(sites.discrete.values()) if sites.discrete else 1
    if total > limit:
        raise ValueError(
            f"the discrete latent sites {dict(sites.discrete)} have {total} combinations of codes, more than "
            f"the {limit} that are enumerated; observe some of them or use guide='importance'"
        )
    return list(itertools.product(*(range(k) for k in sites.discrete.values())))


def sample_discrete(
    program: Callable[..., Any],
    evidence: Mapping[str, Tensor],
    continuous: Mapping[str, Tensor],
    n: int,
    sites: SiteRoles,
    generator: torch.Generator,
    num_samples: int | None = None,
) -> dict[str, Tensor]:
    """Draw the discrete latents given draws of the continuous ones.

    Args:
        program: the program (evidence passed as ``data``).
        evidence: name -> ``(N, dim)`` observed values.
        continuous: name -> ``(S, N, dim)`` draws of the continuous latent sites.
        n: units N.
        sites: the sites of the program's trace.
        generator: source of the draws.
        num_samples: draws S when ``continuous`` is empty (default 1).

    Returns:
        name -> ``(S, N, 1)`` float codes of every discrete latent site.
    """
    combos = code_combinations(sites)
    names = tuple(sites.discrete)
    s = next(iter(continuous.values())).shape[0] if continuous else 1
    dtype = next(iter(evidence.values())).dtype if evidence else torch.get_default_dtype()
    scores = []
    with torch.no_grad(), pyro.validation_enabled(False):
        for combo in combos:
            data = dict(continuous)
            for name, code in zip(names, combo, strict=True):
                data[name] = torch.full((s, n, 1), float(code), dtype=dtype)
            with pyro.plate("_posterior_samples", s, dim=-2):
                trace = poutine.trace(poutine.condition(program, data=data)).get_trace(evidence, n)
            lw = log_joint(trace)
            scores.append(torch.as_tensor(lw, dtype=dtype).expand(s, n))
    logits = torch.stack(scores)  # (C, S, N)
    if not continuous and num_samples:
        logits = logits.expand(len(combos), num_samples, n)
    pick = (logits + gumbel(logits.shape, generator, logits.dtype)).argmax(0)  # (S, N)
    table = torch.tensor(combos, dtype=dtype).reshape(len(combos), len(names))
    chosen = table[pick]  # (S, N, J)
    return {name: chosen[..., j : j + 1] for j, name in enumerate(names)}
