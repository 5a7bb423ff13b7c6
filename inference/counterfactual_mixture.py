"""Counterfactuals with discrete latent sites as exact posterior mixtures.

When the latent sites of a unit are discrete only (e.g. the contact switch c of a gated site,
:class:`models.GatedMechanism`, is not observed), the posterior over them is a finite mixture.
Every combination ``d`` of their codes (:func:`inference.enumeration.code_combinations`) is
weighted by

    w_d = p(d | x_obs) = exp(log p(x_obs, d)) / sum_d' exp(log p(x_obs, d')),

the program's log-joint at the evidence with ``d`` filled in, and given ``d`` every variable is
observed, so :func:`inference.counterfactual` abducts exactly (``u = (x - f_d(pa)) / sigma_d(pa)``
for a gated site) and replays. The counterfactual is the posterior mixture of those answers:

    E[x' | x_obs] = sum_d w_d E[x' | x_obs, d].

``E[x' | x_obs, d]`` is exact when no intervened site is an ancestor of a discrete site; else a
discrete site's counterfactual code depends on its Gumbel noise, whose posterior is sampled
(``num_samples`` draws, as :func:`inference.counterfactual` does).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import pyro
import torch
from pyro import poutine
from torch import Tensor

from inference.counterfactual import counterfactual
from inference.enumeration import code_combinations
from inference.handlers import Intervene
from inference.program import SiteRoles, as_program, log_joint
from inference.state import split_actions
from models.checks import check_int, check_seed
from models.world import as_values

__all__ = ["MixtureCounterfactual", "counterfactual_mixture"]


@dataclass(frozen=True)
class MixtureCounterfactual:
    """A counterfactual as a posterior mixture over the codes of the discrete latent sites.

    Attributes:
        latent: the discrete latent sites, in the order of the codes.
        codes: ``(C, J)`` the combinations of their codes.
        weights: ``(C, N)`` posterior weights ``p(d | x_obs)`` per unit (they sum to 1 over C).
        components: name -> ``(C, K, N, dim)`` the counterfactual mean given each combination.
    """

    latent: tuple[str, ...]
    codes: Tensor
    weights: Tensor
    components: dict[str, Tensor]

    @property
    def mean(self) -> dict[str, Tensor]:
        """The posterior mixture's mean: name -> ``(K, N, dim)``."""
        w = self.weights[:, None, :, None]
        return {k: (w * v).sum(0) for k, v in self.components.items()}


def counterfactual_mixture(
    model: Any,
    factual: Mapping[str, Any],
    interventions: Mapping[str, Any] | Sequence[Mapping[str, Any]],
    *,
    num_samples: int = 1,
    seed: int = 0,
) -> MixtureCounterfactual:
    """What would have happened to each unit, with its discrete latent sites enumerated exactly.

    Args:
        model: a WorldModel or a program made from one.
        factual: name -> ``(N, dim)`` evidence; every variable that is not given must be a
            discrete site (at most :data:`inference.enumeration.MAX_COMBINATIONS` combinations).
        interventions: one scenario or a sequence of K (see :func:`inference.counterfactual`).
        num_samples: Gumbel posterior draws per combination (only needed when an intervened
            site is an ancestor of a discrete site).
        seed: seeds those draws.

    Returns:
        :class:`MixtureCounterfactual`; ``.mean`` is ``(K, N, dim)`` per variable.

    Raises:
        ValueError: a latent continuous site (use :func:`inference.counterfactual`), no
            latent site, or bad factual values, scenarios, ``num_samples`` or ``seed``.
    """
    program = as_program(model)
    graph, world = program.graph, program.world
    num_samples = check_int("num_samples", num_samples, minimum=1)
    seed = check_seed("seed", seed)
    obs, n = as_values(graph, factual, what="factual", dtype=world.dtype)
    if n is None:
        raise ValueError("factual evidence is empty")
    world.check_codes(obs, "factual")
    latent = tuple(v for v in graph.topological_order() if v not in obs)
    continuous = [v for v in latent if v not in world.discrete]
    if continuous or not latent:
        raise ValueError(
            f"counterfactual_mixture enumerates discrete latent sites only; the latent sites are {list(latent)} "
            f"(continuous: {continuous}); use inference.counterfactual"
        )
    combos = code_combinations(SiteRoles((), (), latent, {v: world.discrete[v] for v in latent}, {}))
    evidence, acts = split_actions(program, obs)
    factual_program = Intervene(acts)(program) if acts else program
    dtype = world.dtype
    scores, parts = [], []
    for combo in combos:
        codes = {v: torch.full((n, 1), float(c), dtype=dtype) for v, c in zip(latent, combo, strict=True)}
        with torch.no_grad(), pyro.validation_enabled(False):
            trace = poutine.trace(factual_program).get_trace({**evidence, **codes}, n)
        scores.append(torch.as_tensor(log_joint(trace), dtype=dtype).expand(n))
        result = counterfactual(program, {**obs, **codes}, interventions, num_samples=num_samples, seed=seed)
        parts.append(result.mean)
    weights = torch.softmax(torch.stack(scores), 0)
    components = {k: torch.stack([p[k] for p in parts]) for k in parts[0]}
    return MixtureCounterfactual(latent, torch.tensor(combos, dtype=dtype), weights, components)
