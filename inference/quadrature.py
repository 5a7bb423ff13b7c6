"""Exact state posteriors by quadrature on a grid, for low-dimensional latents.

With D <= 2 continuous latent components per unit (and a few discrete latent sites), the
posterior of unit n is evaluated on a regular grid ``z_g`` (g = 1 .. G) times every
combination of the discrete latent codes ``d_c``:

    log w_gcn = log p_M(x_obs,n, z_g, d_c)        (the program's joint density, every site)
    p(z_g, d_c | x_obs,n) ~= softmax_{g,c}(log w_gcn)

The grid of each unit spans ``mu +- width * s`` per component, the union of the prior's and a
prior-importance-weighted pilot's mean mu and sd s (``pilot`` draws), with ``points`` nodes
for D = 1 and ``floor(budget ** (1 / D))`` per component otherwise. Moments are the weighted
sums over the grid (exact up to the grid spacing); ``num_samples`` draws pick a grid cell by
its weight and jitter the continuous components uniformly inside it. ``edge_mass`` (mass on
the outermost cells) says whether the grid was wide enough.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import pyro
import torch
from pyro import poutine
from torch import Tensor

from inference.diagnostics import EDGE_MASS_THRESHOLD, Diagnostics, ess
from inference.importance import resample, weighted_moments
from inference.program import SiteRoles, log_joint
from inference.svi_state import Fitted
from models.checks import check_float, check_int

__all__ = ["GridOptions", "grid_posterior"]


@dataclass(frozen=True)
class GridOptions:
    """Size and placement of the quadrature grid.

    Attributes:
        points: grid nodes per component for one continuous component, >= 3.
        budget: grid nodes per unit at most for D = 2 (``floor(sqrt(budget))`` per component).
        width: half-width of the grid in pilot sds, > 0.
        pilot: prior draws per unit that place the grid, >= 10.
        max_combinations: most combinations of discrete latent codes, >= 1.
        max_dims: most continuous latent components per unit, 1 or 2.
        chunk: grid nodes x units per program run (memory bound).
    """

    points: int = 2001
    budget: int = 40_000
    width: float = 8.0
    pilot: int = 4000
    max_combinations: int = 64
    max_dims: int = 2
    chunk: int = 4_000_000

    def __post_init__(self) -> None:
        check_int("points", self.points, minimum=3)
        check_int("budget", self.budget, minimum=9)
        check_float("width", self.width, minimum=0.0, min_open=True)
        check_int("pilot", self.pilot, minimum=10)
        check_int("max_combinations", self.max_combinations, minimum=1)
        check_int("max_dims", self.max_dims, minimum=1, maximum=2)
        check_int("chunk", self.chunk, minimum=1)

    def to_dict(self) -> dict[str, Any]:
        """JSON-compatible fields."""
        return dict(self.__dict__)


def check_grid(sites: SiteRoles, options: GridOptions) -> None:
    """Refuse latents the grid cannot hold, naming them and the alternative.

    Raises:
        ValueError: more than ``max_dims`` continuous latent components or more than
            ``max_combinations`` discrete combinations.
    """
    d = sum(sites.dims[k] for k in sites.continuous)
    if d > options.max_dims:
        raise ValueError(
            f"guide='grid' integrates at most {options.max_dims} continuous latent components per unit; "
            f"the program has {d} ({list(sites.continuous)}); use guide='importance' or an SVI guide"
        )
    combos = math.prod(sites.discrete.values()) if sites.discrete else 1
    if combos > options.max_combinations:
        raise ValueError(
            f"guide='grid' enumerates at most {options.max_combinations} combinations of discrete latent "
            f"codes; {dict(sites.discrete)} give {combos}"
        )


def _pilot(
    program: Callable[..., Any],
    evidence: Mapping[str, Tensor],
    n: int,
    sites: SiteRoles,
    options: GridOptions,
) -> tuple[Tensor, Tensor]:
    """``(lo, hi)``, each ``(N, D)``: the grid's range per unit and continuous component."""
    with pyro.plate("_pilot", options.pilot, dim=-2):
        trace = poutine.trace(program).get_trace(evidence, n)
    z = torch.cat(
        [trace.nodes[k]["value"].expand(options.pilot, n, sites.dims[k]) for k in sites.continuous], -1
    )
    lw = log_joint(trace, set(sites.latent))
    lw = lw.expand(options.pilot, n) if isinstance(lw, Tensor) else torch.zeros(options.pilot, n)
    weights = torch.softmax(lw.double(), 0).to(z.dtype)
    post_mean, post_sd = weighted_moments(z, weights)
    prior_mean, prior_sd = z.mean(0), z.std(0)
    floor = 1e-3 * prior_sd.clamp_min(1e-6)
    lo = torch.minimum(
        prior_mean - options.width * prior_sd, post_mean - options.width * post_sd.clamp_min(floor)
    )
    hi = torch.maximum(
        prior_mean + options.width * prior_sd, post_mean + options.width * post_sd.clamp_min(floor)
    )
    return lo, hi


def grid_posterior(
    program: Callable[..., Any],
    evidence: Mapping[str, Tensor],
    n: int,
    sites: SiteRoles,
    num_samples: int,
    options: GridOptions,
    generator: torch.Generator,
) -> Fitted:
    """Exact posterior of every unit on a grid (module docstring).

    Args:
        program: the program.
        evidence: name -> ``(N, dim)`` observed values.
        n: units N.
        sites: the sites of the program's trace.
        num_samples: draws S per unit.
        options: grid size and placement.
        generator: source of the draws (the pilot uses torch's RNG, seeded by the caller).

    Returns:
        :class:`inference.svi_state.Fitted` (no losses).
    """
    check_grid(sites, options)
    continuous, discrete = sites.continuous, tuple(sites.discrete)
    d = sum(sites.dims[k] for k in continuous)
    with torch.no_grad(), pyro.validation_enabled(False):
        dtype = next(iter(evidence.values())).dtype if evidence else torch.get_default_dtype()
        if d:
            lo, hi = _pilot(program, evidence, n, sites, options)
            per_dim = options.points if d == 1 else math.floor(options.budget ** (1 / d))
            t = torch.linspace(0, 1, per_dim, dtype=lo.dtype)
            nodes = torch.cartesian_prod(*([t] * d)).reshape(-1, d)  # (Gc, D) in [0, 1]
            index = torch.cartesian_prod(*([torch.arange(per_dim)] * d)).reshape(-1, d)
            step = (hi - lo) / (per_dim - 1)  # (N, D)
        else:
            nodes, index, per_dim = torch.zeros(1, 0), torch.zeros(1, 0, dtype=torch.long), 1
            lo = hi = step = torch.zeros(n, 0, dtype=dtype)
        codes = list(itertools.product(*(range(sites.discrete[k]) for k in discrete))) or [()]
        g_cont, total = nodes.shape[0], nodes.shape[0] * len(codes)
        lw_all, grid = _log_weights(program, evidence, n, sites, options, (nodes, lo, hi), codes, dtype)
        weights = torch.softmax(lw_all.double(), 0).to(lw_all.dtype)
        mean, sd = {}, {}
        for k, v in grid.items():
            mean[k], sd[k] = weighted_moments(v, weights)
        samples = resample(grid, weights, num_samples, generator)
        if d:
            # jitter inside the cell: +- step / 2 per component
            jitter = torch.rand(num_samples, n, d, generator=generator, dtype=lo.dtype) - 0.5
            col = 0
            for k in continuous:
                dk = sites.dims[k]
                samples[k] = samples[k] + jitter[..., col : col + dk] * step[:, col : col + dk]
                col += dk
            node_idx = torch.arange(total) % g_cont
            edge = ((index[node_idx] == 0) | (index[node_idx] == per_dim - 1)).any(-1)
            edge_mass = weights[edge].sum(0)
        else:
            edge_mass = torch.zeros(n, dtype=weights.dtype)
    return Fitted(samples, mean, sd, (), _diagnostics(lw_all, edge_mass, per_dim**d * len(codes)))


def _log_weights(
    program: Callable[..., Any],
    evidence: Mapping[str, Tensor],
    n: int,
    sites: SiteRoles,
    options: GridOptions,
    box: tuple[Tensor, Tensor, Tensor],
    codes: list[tuple[int, ...]],
    dtype: torch.dtype,
) -> tuple[Tensor, dict[str, Tensor]]:
    """The program's log joint ``(G, N)`` at every grid node x code combination, and the latent values there.

    ``box`` holds the nodes ``(Gc, D)`` in [0, 1] and the per-unit range ``lo``, ``hi`` ``(N, D)``;
    the nodes run in chunks of ``options.chunk`` nodes x units.
    """
    nodes, lo, hi = box
    continuous, discrete = sites.continuous, tuple(sites.discrete)
    g_cont, total = nodes.shape[0], nodes.shape[0] * len(codes)
    per_run = max(1, min(total, options.chunk // max(n, 1)))
    log_w, values = [], {k: [] for k in sites.latent}
    for start in range(0, total, per_run):
        ids = torch.arange(start, min(start + per_run, total))
        node, code = ids % g_cont, ids // g_cont
        z = lo + nodes[node][:, None, :].to(lo.dtype) * (hi - lo)  # (g, N, D)
        data, col = {}, 0
        for k in continuous:
            data[k] = z[..., col : col + sites.dims[k]]
            col += sites.dims[k]
        for j, k in enumerate(discrete):
            table = torch.tensor([c[j] for c in codes], dtype=dtype)
            data[k] = table[code][:, None, None].expand(len(ids), n, 1)
        with pyro.plate("_grid", len(ids), dim=-2):
            trace = poutine.trace(poutine.condition(program, data=data)).get_trace(evidence, n)
        lw = log_joint(trace, set())
        log_w.append(lw.expand(len(ids), n))
        for k in sites.latent:
            values[k].append(data[k])
    return torch.cat(log_w), {k: torch.cat(v) for k, v in values.items()}


def _diagnostics(lw_all: Tensor, edge_mass: Tensor, nodes: int) -> Diagnostics:
    """The grid's diagnostics: units with too much mass on the edge are flagged."""
    flagged = tuple(int(i) for i in torch.nonzero(edge_mass > EDGE_MASS_THRESHOLD).flatten())
    message = (
        f"grid: {len(flagged)} units have more than {EDGE_MASS_THRESHOLD:g} of their mass on the grid's edge; "
        "raise GridOptions.width"
        if flagged
        else f"grid: {nodes} nodes per unit, edge mass <= {EDGE_MASS_THRESHOLD:g} everywhere"
    )
    return Diagnostics("grid", ess=ess(lw_all), edge_mass=edge_mass, flagged=flagged, message=message)
