"""State posteriors (thesis Eq. 4.41-4.42): p(z | x_obs) over the latent sites of a program.

The latent sites are read from a trace of the program actually run with the evidence: every
variable site that is neither observed nor intervened on (by ``do``, by a handler entered
with ``with``, or by executed actions in the evidence, which are applied as ``do``). Each
unit of the plate gets its own posterior. The methods (``guide=``):

* ``"normal"``, ``"mvn"``, ``"flow"``: SVI with a mean-field, full-rank or normalizing-flow
  guide (:mod:`inference.svi_state`); discrete latents summed by ``TraceEnum_ELBO``.
* ``"importance"``: self-normalised importance sampling from the prior
  (:mod:`inference.importance`).
* ``"grid"``: exact quadrature for at most 2 continuous latent components per unit and a few
  discrete ones (:mod:`inference.quadrature`).

Every result carries :class:`inference.diagnostics.Diagnostics` (Pareto-k, effective sample
size or grid edge mass); a :class:`inference.diagnostics.PoorPosteriorWarning` is issued when
some units are flagged, e.g. when a Gaussian guide keeps only one of two modes.
"""

from __future__ import annotations

import copy
import logging
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import pyro
import torch
from torch import Tensor

from inference.active import active_handlers
from inference.diagnostics import Diagnostics, PoorPosteriorWarning
from inference.frozen import frozen_parameters
from inference.handlers import Intervene, MeasurementScale, ProgramMessenger
from inference.importance import ImportanceOptions, importance_posterior
from inference.program import Program, SiteRoles, as_program, check_active_handlers, read_sites
from inference.quadrature import GridOptions, grid_posterior
from inference.svi_state import SVI_GUIDES, SVIOptions, svi_posterior
from models.checks import (
    check_bool,
    check_choice,
    check_float,
    check_int,
    check_seed,
    describe,
)
from models.graph import CausalGraph
from models.variables import Role
from models.world import as_values, check_action_bounds

__all__ = [
    "GUIDES",
    "GridOptions",
    "ImportanceOptions",
    "SVIOptions",
    "StateResult",
    "infer_state",
    "split_actions",
]

log = logging.getLogger(__name__)

#: The posterior methods of :func:`infer_state` and the option type each takes.
GUIDES: dict[str, type] = {
    "normal": SVIOptions,
    "mvn": SVIOptions,
    "flow": SVIOptions,
    "importance": ImportanceOptions,
    "grid": GridOptions,
}


@dataclass(frozen=True)
class StateResult:
    """Posterior over the latent sites of one program and evidence.

    Attributes:
        latent: names of the inferred sites, in the order the program ran them.
        mean, sd: name -> ``(N, dim)`` posterior mean and standard deviation (exact for the
            grid, weighted for importance sampling, the guide's for SVI).
        samples: name -> ``(S, N, dim)`` posterior draws.
        losses: -ELBO per unit at every SVI step (empty for importance and grid).
        guide: the method, a key of :data:`GUIDES`.
        diagnostics: the fit diagnostics.
        graph: the program's graph (a counterfactual with ``posterior=`` checks it).
        evidence: name -> ``(N, dim)`` the observed values it was inferred from.
        autoguide: the fitted Pyro autoguide (SVI methods), else None.
        param_state: its parameters (``pyro.get_param_store().scope(param_state)``
            restores them for further use of ``autoguide``).
    """

    latent: tuple[str, ...]
    mean: dict[str, Tensor]
    sd: dict[str, Tensor]
    samples: dict[str, Tensor]
    losses: tuple[float, ...]
    guide: str
    diagnostics: Diagnostics
    graph: CausalGraph = field(repr=False)
    evidence: dict[str, Tensor] = field(default_factory=dict, repr=False)
    autoguide: Any = field(default=None, repr=False)
    param_state: dict[str, Any] = field(default_factory=dict, repr=False)

    @property
    def loss(self) -> tuple[float, ...]:
        """Alias of :attr:`losses`."""
        return self.losses

    @property
    def num_samples(self) -> int:
        """S, the draws per unit."""
        return next(iter(self.samples.values())).shape[0]

    def interval(self, name: str, level: float = 0.9) -> tuple[Tensor, Tensor]:
        """Equal-tailed credible interval from the samples: two ``(N, dim)`` tensors."""
        level = check_float("level", level, minimum=0.0, maximum=1.0, min_open=True, max_open=True)
        if not isinstance(name, str) or name not in self.samples:
            raise ValueError(f"{name!r} is not a latent site; latent: {list(self.latent)}")
        q = torch.tensor([(1 - level) / 2, (1 + level) / 2], dtype=self.samples[name].dtype)
        lo, hi = torch.quantile(self.samples[name], q, dim=0)
        return lo, hi

    def to_dict(self) -> dict[str, Any]:
        """JSON-compatible summary: means, sds, the last loss and the diagnostics."""
        return {
            "latent": list(self.latent),
            "guide": self.guide,
            "mean": {k: v.tolist() for k, v in self.mean.items()},
            "sd": {k: v.tolist() for k, v in self.sd.items()},
            "num_samples": self.num_samples,
            "final_loss": self.losses[-1] if self.losses else None,
            "num_steps": len(self.losses),
            "diagnostics": self.diagnostics.to_dict(),
        }


def measurement_sites(program: Program) -> tuple[str, ...]:
    """The sites of every MeasurementScale of ``program`` and of those entered with ``with``."""
    frames = [*program.handlers, *reversed(active_handlers())]
    return tuple(n for f in frames if isinstance(f, MeasurementScale) for n in f.site_names())


def split_actions(model: Any, observed: Mapping[str, Tensor]) -> tuple[dict[str, Tensor], dict[str, Tensor]]:
    """Separate executed actions (applied as do, Eq. 4.30) from observed evidence: ``(evidence, actions)``."""
    graph = model.graph
    acts = {k: v for k, v in observed.items() if graph[k].role is Role.ACTION}
    evidence = {k: v for k, v in observed.items() if k not in acts}
    return evidence, acts


def _options(guide: str, options: Any) -> Any:
    kind = GUIDES[guide]
    if options is None:
        options = kind()
    if not isinstance(options, kind):
        raise ValueError(f"guide={guide!r} takes options={kind.__name__}(...), got {describe(options)}")
    return options


def infer_state(
    model: Any,
    observed: Mapping[str, Any],
    *,
    guide: str = "normal",
    num_steps: int = 500,
    num_samples: int = 1000,
    options: SVIOptions | ImportanceOptions | GridOptions | None = None,
    seed: int = 0,
    progress_bar: bool = False,
) -> StateResult:
    """Posterior over the latent sites given the observed sites.

    Args:
        model: a :class:`models.WorldModel` or a program made from one (``do(model, ...)``,
            ``MeasurementScale(...)(model)``, ...). Handlers entered with ``with`` around the
            call act too.
        observed: name -> ``(N, dim)`` evidence (category codes for discrete sites), or a
            table (:mod:`models.tables`).
            Executed actions in it are applied as ``do(action)``, not conditioned on.
        guide: the posterior method, a key of :data:`GUIDES` (module docstring).
        num_steps: SVI steps (SVI guides only).
        num_samples: posterior draws S returned in ``samples``.
        options: :class:`SVIOptions`, :class:`ImportanceOptions` or :class:`GridOptions`,
            matching ``guide``; None for the defaults.
        seed: seeds the method (torch's RNG in a forked context and local generators); the
            caller's torch, numpy and Python RNG states are left as they were.
        progress_bar: show a tqdm bar over SVI steps.

    Returns:
        :class:`StateResult`.

    Raises:
        ValueError: a model that is not a WorldModel or program, bad evidence (see
            :func:`models.world.as_values`; also category codes out of range), executed
            actions outside their bounds, an unknown guide, options of the wrong type,
            sites both observed and intervened, no latent site, a grid over too many
            latent components, or handlers naming unknown sites.
        FloatingPointError: the ELBO became NaN or inf.
    """
    program = as_program(model)
    graph = program.graph
    guide = check_choice("guide", guide, sorted(GUIDES))
    num_steps = check_int("num_steps", num_steps, minimum=1)
    num_samples = check_int("num_samples", num_samples, minimum=1)
    seed = check_seed("seed", seed)
    progress_bar = check_bool("progress_bar", progress_bar)
    obs, n = _evidence(program, observed)
    options = _options(guide, options)
    check_active_handlers(graph)
    evidence, acts = split_actions(program, obs)
    if acts:
        program = Intervene(acts)(program)
    param_store = pyro.get_param_store()
    with param_store.scope() as param_state, torch.random.fork_rng(), frozen_parameters(program.world):
        torch.manual_seed(seed)
        generator = torch.Generator().manual_seed(seed)
        sites = _latent_sites(program, evidence, n)
        fitted = _posterior(
            program, guide, evidence, n, sites, num_steps, num_samples, options, progress_bar, generator
        )
    if not fitted.diagnostics.ok:
        warnings.warn(fitted.diagnostics.message, PoorPosteriorWarning, stacklevel=2)
    log.debug("infer_state(%s): %s", guide, fitted.diagnostics.message)
    return StateResult(
        sites.latent,
        fitted.mean,
        fitted.sd,
        fitted.samples,
        fitted.losses,
        guide,
        fitted.diagnostics,
        graph,
        dict(obs),
        fitted.autoguide,
        param_state if fitted.autoguide is not None else {},
    )


def _evidence(program: Program, observed: Mapping[str, Any]) -> tuple[dict[str, Tensor], int]:
    """The observed values name -> ``(N, dim)`` and N, checked against the program's graph."""
    graph = program.graph
    obs, n = as_values(graph, observed, what="observed", dtype=program.dtype)
    if n is None:
        raise ValueError("observed is empty; state inference needs evidence")
    check_action_bounds(graph, obs, "observed")
    program.world.check_codes(obs, "observed")
    return obs, n


def _latent_sites(program: Program, evidence: Mapping[str, Tensor], n: int) -> SiteRoles:
    """The sites of one run of the program; refuses evidence on intervened sites and no latent site."""
    sites = read_sites(program, evidence, n)
    both = sorted(set(evidence) & set(sites.intervened))
    if both:
        raise ValueError(f"variables {both} are both observed and intervened on; pick one")
    if not sites.latent:
        raise ValueError("every variable is observed or intervened on; there is no latent site to infer")
    unobserved = sorted(set(measurement_sites(program)) - set(evidence))
    if unobserved:
        raise ValueError(
            f"MeasurementScale names {unobserved}, which are not observed sites; observed: {sorted(evidence)}"
        )
    return sites


def _posterior(
    program: Program,
    guide: str,
    evidence: Mapping[str, Tensor],
    n: int,
    sites: SiteRoles,
    num_steps: int,
    num_samples: int,
    options: Any,
    progress_bar: bool,
    generator: torch.Generator,
) -> Any:
    """Run the posterior method ``guide``."""
    if guide in SVI_GUIDES:
        return svi_posterior(
            _with_outer_handlers(program),
            evidence,
            n,
            sites,
            guide,
            num_steps,
            num_samples,
            options,
            progress_bar,
            generator,
        )
    if guide == "importance":
        return importance_posterior(program, evidence, n, sites, num_samples, options, generator)
    return grid_posterior(program, evidence, n, sites, num_samples, options, generator)


def _with_outer_handlers(program: Program) -> Program:
    """The program with copies of pal's handlers entered with ``with`` as its outermost handlers.

    Autoguides trace the model inside ``poutine.block``, which hides the handlers entered
    with ``with``, so the program carries them itself.
    """
    outer = [copy.copy(f) for f in active_handlers() if isinstance(f, ProgramMessenger)]
    if outer:
        return Program(program.world, (*program.handlers, *outer))
    return program
