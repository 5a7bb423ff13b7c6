"""Abduction, step 1 of a counterfactual (thesis Eq. 4.43).

:func:`abduct` gives the standardised residuals of every site given complete values (Gumbel
posterior noise for a discrete site), through :class:`inference.AbductNoise` or, on a plain
model, its torch twin. When some sites are latent, :func:`_posterior` gives the state posterior
that completes the evidence before each draw is abducted.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import pyro
import torch
from torch import Tensor

from inference.handlers import AbductNoise, Intervene
from inference.interventions import check_interventions
from inference.program import Program, as_program, read_sites, same_graph
from inference.quadrature import GridOptions, check_grid
from inference.state import GUIDES, StateResult, infer_state
from models.checks import check_int, check_mapping, check_seed, describe
from models.folded import loc_scale
from models.world import WorldModel, as_values

__all__ = ["abduct"]


def abduct(
    model: Any,
    values: Mapping[str, Tensor],
    n: int,
    interventions: Mapping[str, Any] | None = None,
    *,
    seed: int = 0,
) -> dict[str, Tensor]:
    """Standardised residuals of every site given complete ``values`` (Eq. 4.43).

    Args:
        model: a WorldModel or a program made from one.
        values: name -> ``(n, dim)`` for every variable (executed actions included).
        n: number of units.
        interventions: assignments in force in the factual world (their sites get eps 0).
        seed: seeds the Gumbel posterior draws of discrete sites (a local generator).

    Returns:
        name -> ``(n, dim)`` (``(n, K)`` Gumbel noise for a discrete site).
    """
    program = as_program(model)
    n = check_int("n", n, minimum=1)
    seed = check_seed("seed", seed)
    world = program.world
    values, _ = as_values(program.graph, values, n=n, what="values", dtype=world.dtype)
    world.check_codes(values, "values")
    interventions = check_interventions(
        program.graph,
        check_mapping("interventions", interventions, allow_none=True),
        world.dtype,
        world.discrete,
    )
    return _abduct(program, values, n, interventions, torch.Generator().manual_seed(seed))


def _abduct(
    program: Program,
    values: Mapping[str, Tensor],
    n: int,
    interventions: Mapping[str, Any],
    generator: torch.Generator,
) -> dict[str, Tensor]:
    if interventions:
        program = Intervene(interventions)(program)
    abduction = AbductNoise(generator)
    # Inputs were checked by ``as_values``; Pyro's per-site argument validation only adds cost.
    with torch.no_grad(), pyro.validation_enabled(False):
        abduction(program)({k: v for k, v in values.items() if k not in interventions}, n)
    return abduction.noise


def _torch_abduction(model: WorldModel, acts: Mapping[str, Tensor]) -> bool:
    """Whether :func:`_abduct_plain` gives the program's abduction: no discrete site, every action set."""
    graph = model.graph
    return not model.discrete and all(a in acts for a in graph.actions)


def _abduct_plain(
    model: WorldModel, values: Mapping[str, Tensor], acts: Mapping[str, Tensor]
) -> dict[str, Tensor]:
    """The torch twin of :class:`AbductNoise` on a plain model with complete values (tests hold them equal).

    ``eps = (x - loc) / scale`` per site in topological order (0 where the scale is 0), and 0
    at the executed actions, which the factual world sets by ``do``.
    """
    graph = model.graph
    noise: dict[str, Tensor] = {}
    with torch.no_grad():
        for name in graph.topological_order():
            x = values[name]
            if name in acts:
                noise[name] = torch.zeros_like(x)
                continue
            if graph.is_root(name):
                loc, scale = model.root_priors.get(name)
            else:
                loc, scale = loc_scale(model.mechanism(name), x.shape[0])(model._parents(name, values))
            loc, scale = loc.expand_as(x), scale.expand_as(x)
            safe = torch.where(scale > 0, scale, torch.ones_like(scale))
            noise[name] = torch.where(scale > 0, (x - loc) / safe, torch.zeros_like(loc))
    return noise


def _posterior(
    program: Program,
    obs: Mapping[str, Tensor],
    evidence: Mapping[str, Tensor],
    n: int,
    latent: tuple[str, ...],
    posterior: Any,
    guide: str,
    num_samples: int,
    options: Any,
    seed: int,
) -> StateResult:
    """The given posterior (checked against the program and evidence) or a new one."""
    if posterior is not None:
        if not isinstance(posterior, StateResult):
            raise ValueError(f"posterior must be a StateResult from infer_state, got {describe(posterior)}")
        same_graph(program.graph, posterior.graph, "posterior")
        if set(posterior.latent) != set(latent):
            raise ValueError(
                f"posterior is over {sorted(posterior.latent)}, but the latent sites of this program and "
                f"evidence are {sorted(latent)}; infer it from the same program and factual evidence"
            )
        for k, v in evidence.items():
            given = posterior.evidence.get(k)
            if given is None or given.shape != v.shape or not torch.equal(given.to(v.dtype), v):
                raise ValueError(
                    f"posterior was inferred from other evidence for {k!r}; pass the factual values it was "
                    "inferred from (no evidence counted twice: the posterior comes from the factual world)"
                )
        return posterior
    if guide == "auto":
        with torch.random.fork_rng():
            torch.manual_seed(seed)
            sites = read_sites(program, evidence, n)
        try:
            check_grid(sites, options if isinstance(options, GridOptions) else GridOptions())
            guide = "grid"
        except ValueError:
            guide = "normal"
    if options is not None and not isinstance(options, GUIDES[guide]):
        options = None
    return infer_state(program, obs, guide=guide, num_samples=num_samples, seed=seed, options=options)
