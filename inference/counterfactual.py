"""Counterfactuals by abduction, action and prediction (thesis §1.3.2, Eq. 4.43).

1. Abduction: for each unit, the standardised residuals ``eps_i = (x_i - f_i(pa_i)) / sigma_i(pa_i)``
   compatible with the factual evidence. If every variable is observed this is exact. If
   some are latent, a posterior over them is first inferred from the factual evidence in
   one world (:func:`inference.infer_state`), and each posterior draw is completed and
   abducted in turn (:mod:`inference.abduction`).
2. Action: ``do`` the scenario's interventions.
3. Prediction: replay the abducted residuals through the intervened program,
   ``x_i' = f_i(pa_i') + sigma_i(pa_i') * eps_i``.

The rule holds for every location-scale site. A heteroscedastic site
(:class:`models.HeteroscedasticMechanism`) uses its scale at the factual parents for
abduction and at the counterfactual parents for prediction. An ensemble site
(:class:`models.EnsembleMechanism`) is the moment-matched Normal of its K equally weighted
members, ``loc = mean_k m_k``, ``scale^2 = mean_k s_k^2 + mean_k (m_k - loc)^2``, so it is
abducted and replayed exactly as that Normal: the member index is not a latent of the
program, and no member is picked per unit.

A discrete site (:mod:`models.discrete`) is the Gumbel-max SCM ``x = argmax_k (l_k(pa) + g_k)``
(Oberst and Sontag 2019): abduction draws its ``(N, K)`` Gumbel noise from the exact posterior
given the observed category (the top-down construction), and prediction takes the argmax
under the counterfactual parents. Its Gumbel draws matter only where a scenario recomputes it
without setting it (it descends from an intervention): a site that is set (a binary treatment
under do(T = 0) and do(T = 1)) or that no intervention reaches keeps one value in every draw.
With every variable observed and no such site, one pass answers the query and ``exact`` is
True. Otherwise only those sites get S draws, and only they and their descendants are replayed
S times (:mod:`inference.counterfactual_fast`); ``exact`` is then False.

A scenario that repeats an earlier one (same sites, equal values, the same shift callable) is
computed once, with a warning, and its answer given in both places.

The model may be a program: ``counterfactual(do(m, {...}), ...)`` or under handlers entered
with ``with`` (an ``Intervene`` there holds in the factual and the counterfactual world; a
``MeasurementScale`` sets the scale of its site in both). Latent sites are read from a trace of
the factual program. ``posterior=`` takes a :class:`inference.StateResult` of the same program
and evidence instead of inferring one; otherwise ``guide`` picks the method
(:func:`inference.infer_state`; ``"auto"``: the exact grid when at most 2 continuous latent
components per unit, else the mean-field guide).

Abduction runs once; the K scenarios (and S posterior draws) are then one batch of
``K * S * N`` units, so the cost is linear in K and S. A plain :class:`models.WorldModel` with
no handler active takes the fast path (:mod:`inference.counterfactual_fast`): the scenarios are
stacked on a batch axis, each recomputes only the descendants of its own interventions, and
the sites it does not reach keep their factual values without being copied per scenario.
Each scenario still evaluates its descendants' mechanisms on its own N rows, so the time of K
scenarios grows by that replay per scenario over the shared checks and abduction.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import pyro
import torch
from pyro import poutine
from torch import Tensor

from inference.abduction import _posterior, abduct
from inference.active import no_handler_active
from inference.counterfactual_fast import _fast, _stacked
from inference.handlers import AbductNoise, Intervene, ReplayNoise
from inference.interventions import action_bounds, check_interventions
from inference.program import Program, as_program, check_active_handlers, read_sites
from inference.state import GUIDES, StateResult, split_actions
from models.checks import (
    check_choice,
    check_float,
    check_int,
    check_seed,
    describe,
)
from models.world import as_values, check_action_bounds

__all__ = ["CounterfactualResult", "abduct", "counterfactual"]


@dataclass(frozen=True)
class CounterfactualResult:
    """Counterfactual values under each scenario.

    Attributes:
        samples: name -> ``(S, K, N, dim)``; S = 1 when the evidence was complete and no
            scenario recomputes a discrete site it does not set (the module docstring).
        noise: name -> ``(S, N, dim)`` abducted standardised residuals (``(S, N, K)``
            Gumbel noise for a discrete site).
        exact: True when every variable was observed and no scenario recomputes a discrete
            site it does not set (one draw answers the query).
        posterior: the state posterior used for latent variables, else None.
    """

    samples: dict[str, Tensor]
    noise: dict[str, Tensor]
    exact: bool
    posterior: StateResult | None = None

    @property
    def mean(self) -> dict[str, Tensor]:
        """Mean over posterior draws: name -> ``(K, N, dim)``."""
        return {k: v.mean(0) for k, v in self.samples.items()}

    def interval(self, name: str, level: float = 0.9) -> tuple[Tensor, Tensor]:
        """Equal-tailed interval over posterior draws: two ``(K, N, dim)`` tensors."""
        if not isinstance(name, str) or name not in self.samples:
            raise ValueError(f"unknown variable {name!r}; known: {list(self.samples)}")
        level = check_float("level", level, minimum=0.0, maximum=1.0, min_open=True, max_open=True)
        q = torch.tensor([(1 - level) / 2, (1 + level) / 2], dtype=self.samples[name].dtype)
        lo, hi = torch.quantile(self.samples[name], q, dim=0)
        return lo, hi

    def probability(self, name: str, code: float) -> Tensor:
        """``P(name' = code)`` over the draws, ``(K, N)``, for a discrete (or any) site."""
        if not isinstance(name, str) or name not in self.samples:
            raise ValueError(f"unknown variable {name!r}; known: {list(self.samples)}")
        code = check_float("code", code)
        return (self.samples[name][..., 0] == code).to(self.samples[name].dtype).mean(0)

    def to_dict(self) -> dict[str, Any]:
        """JSON-compatible summary: means and 90 % intervals per scenario, unit and site."""
        out: dict[str, Any] = {"exact": self.exact, "num_samples": next(iter(self.samples.values())).shape[0]}
        out["mean"] = {k: v.tolist() for k, v in self.mean.items()}
        out["interval90"] = {k: [t.tolist() for t in self.interval(k)] for k in self.samples}
        if self.posterior is not None:
            out["posterior"] = self.posterior.to_dict()
        return out


def _scenarios(program: Program, interventions: Any, n: int) -> list[dict[str, Any]]:
    if isinstance(interventions, Mapping):
        scenarios = [interventions]
    elif isinstance(interventions, (list, tuple)):
        scenarios = list(interventions)
    else:
        raise ValueError(
            f"interventions must be a mapping (one scenario) or a list of mappings, got {describe(interventions)}"
        )
    if not scenarios:
        raise ValueError("interventions is an empty sequence; give at least one scenario")
    for k, sc in enumerate(scenarios):
        if not isinstance(sc, Mapping):
            raise ValueError(f"scenario {k} must be a mapping name -> value, got {describe(sc)}")
    world = program.world
    out = [check_interventions(program.graph, s, world.dtype, world.discrete) for s in scenarios]
    for sc in out:
        for name, spec in sc.items():
            if isinstance(spec, Tensor) and spec.ndim == 2 and spec.shape[0] != n:
                raise ValueError(
                    f"intervention on {name!r} has {spec.shape[0]} rows, expected {n} (one per unit)"
                )
    return out


def counterfactual(
    model: Any,
    factual: Mapping[str, Any],
    interventions: Mapping[str, Any] | Sequence[Mapping[str, Any]],
    *,
    posterior: StateResult | None = None,
    guide: str = "auto",
    num_samples: int = 1000,
    options: Any = None,
    seed: int = 0,
) -> CounterfactualResult:
    """What would have happened to each unit under other interventions.

    Args:
        model: a WorldModel or a program made from one; handlers entered with ``with``
            act in both worlds.
        factual: name -> ``(N, dim)`` evidence from the factual world, or a table
            (:mod:`models.tables`). Executed actions are part of it and are treated as
            interventions of that world.
        interventions: one scenario (a mapping name -> value, ``(N, dim)`` tensor or
            shift callable) or a sequence of K scenarios evaluated in one batch.
        posterior: a :class:`inference.StateResult` of the same program and factual
            evidence to use for the latent sites (else one is inferred).
        guide: the method when a posterior is inferred: ``"auto"`` or a key of
            :data:`inference.state.GUIDES`.
        num_samples: draws S (posterior draws, and Gumbel posterior draws of discrete sites).
        options: the options of ``guide`` (see :func:`inference.infer_state`).
        seed: seeds the posterior and the Gumbel draws (local generators, forked RNG).

    Returns:
        :class:`CounterfactualResult` with samples of shape ``(S, K, N, dim)``.

    Raises:
        ValueError: a model that is not a WorldModel or program, bad factual values (see
            :func:`models.world.as_values`; category codes out of range), executed actions
            outside their bounds, bad scenarios (see :func:`inference.do`), a posterior of
            another graph, latent sites or evidence, an unknown guide, or bad
            ``num_samples`` or ``seed``.
    """
    program = as_program(model)
    graph, world = program.graph, program.world
    num_samples = check_int("num_samples", num_samples, minimum=1)
    seed = check_seed("seed", seed)
    guide = check_choice("guide", guide, ["auto", *sorted(GUIDES)])
    obs, n = as_values(graph, factual, what="factual", dtype=world.dtype)
    if n is None:
        raise ValueError("factual evidence is empty")
    check_action_bounds(graph, obs, "factual")
    world.check_codes(obs, "factual")
    scenarios = _scenarios(program, interventions, n)
    check_active_handlers(graph)
    evidence, acts = split_actions(program, obs)
    plain = not program.handlers and no_handler_active()
    factual_program = Intervene(acts)(program) if acts else program
    if plain:  # nothing can change the roles of the sites: they are the graph's
        latent = tuple(v for v in graph.topological_order() if v not in obs)
    else:
        with torch.random.fork_rng():
            torch.manual_seed(seed)
            latent = read_sites(factual_program, evidence, n).latent
    state = None
    if latent or posterior is not None:
        state = _posterior(program, obs, evidence, n, latent, posterior, guide, num_samples, options, seed)
    unique, index = _unique(scenarios)
    uncertain = _uncertain(graph, world.discrete, unique)
    s = state.num_samples if state is not None else (num_samples if uncertain else 1)
    generator = torch.Generator().manual_seed(seed)
    if plain:  # draws only from the local generator
        samples, noise = _fast(world, evidence, acts, state, latent, unique, uncertain, s, n, generator)
    else:
        with torch.random.fork_rng():  # nothing is drawn from it, but a handler might: keep it as it was
            torch.manual_seed(seed)
            samples, noise = _general(program, evidence, acts, state, latent, unique, s, n, generator)
    if len(unique) < len(scenarios):
        samples = {k: v[:, index] for k, v in samples.items()}
    return CounterfactualResult(samples, noise, exact=not latent and not uncertain, posterior=state)


def _uncertain(graph: Any, discrete: Any, scenarios: list[dict[str, Any]]) -> set[str]:
    """The discrete sites that some scenario recomputes without setting them (their Gumbel draws count).

    A discrete site that a scenario sets, or that descends from none of its interventions,
    takes its factual (or set) value in every draw: with every site observed and no such
    site left, the counterfactual is one deterministic pass.
    """
    out: set[str] = set()
    for sc in scenarios:
        below = set().union(*(graph.descendants(k) for k in sc)) if sc else set()
        out |= {d for d in discrete if d in below and d not in sc}
    return out


def _same_spec(a: Any, b: Any) -> bool:
    if isinstance(a, Tensor) and isinstance(b, Tensor):
        return a.shape == b.shape and bool(torch.equal(a, b))
    return a is b


def _unique(scenarios: list[dict[str, Any]]) -> tuple[list[dict[str, Any]], list[int]]:
    """The distinct scenarios and, for each given one, its index among them.

    A scenario that repeats an earlier one (same sites, equal values, the same shift
    callable) is computed once; a warning names both.
    """
    unique: list[dict[str, Any]] = []
    index: list[int] = []
    for k, sc in enumerate(scenarios):
        for j, other in enumerate(unique):
            if sc.keys() == other.keys() and all(_same_spec(sc[v], other[v]) for v in sc):
                first = index.index(j)
                warnings.warn(
                    f"scenario {k} repeats scenario {first} ({_describe(sc)}); it is computed once and "
                    "its answer given twice",
                    UserWarning,
                    stacklevel=3,
                )
                index.append(j)
                break
        else:
            index.append(len(unique))
            unique.append(sc)
    return unique, index


def _describe(scenario: Mapping[str, Any]) -> str:
    parts = []
    for name, spec in scenario.items():
        if isinstance(spec, Tensor) and spec.numel() <= 4:
            parts.append(f"{name}={spec.reshape(-1).tolist()}")
        else:
            parts.append(f"{name}={describe(spec)}")
    return "do(" + ", ".join(parts) + ")" if parts else "no intervention"


def _general(
    program: Program,
    evidence: Mapping[str, Tensor],
    acts: Mapping[str, Tensor],
    state: StateResult | None,
    latent: tuple[str, ...],
    scenarios: list[dict[str, Any]],
    s: int,
    n: int,
    generator: torch.Generator,
) -> tuple[dict[str, Tensor], dict[str, Tensor]]:
    """Any program: the draws and the scenarios are plates of the program's batch."""
    graph = program.graph
    factual = Intervene(acts)(program) if acts else program
    draws = {k: state.samples[k] for k in latent} if state is not None else {}
    abduction = AbductNoise(generator)
    with torch.no_grad(), pyro.validation_enabled(False), pyro.plate("_draws", s, dim=-2):
        poutine.condition(abduction(factual), data=draws)(evidence, n)
    k_total = len(scenarios)
    noise = {}
    for name, eps in abduction.noise.items():
        eps = eps.expand(s, n, eps.shape[-1])
        noise[name] = eps
    replay = {k: v.expand(k_total, *v.shape) for k, v in noise.items() if k not in acts}
    assign = _stacked([{**acts, **sc} for sc in scenarios])
    cf = Intervene(assign, bounds=action_bounds(graph, assign))(
        ReplayNoise(replay, default="expected")(program)
    )
    with (
        torch.no_grad(),
        pyro.validation_enabled(False),
        pyro.plate("_scenarios", k_total, dim=-3),
        pyro.plate("_draws", s, dim=-2),
    ):
        values = cf(None, n)
    samples = {
        k: v.expand(k_total, s, n, v.shape[-1]).transpose(0, 1).contiguous() for k, v in values.items()
    }
    return samples, noise
