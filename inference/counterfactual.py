"""Counterfactuals by abduction, action and prediction (thesis §1.3.2, Eq. 4.43).

1. Abduction: for each unit, the standardised residuals ``eps_i = (x_i - f_i(pa_i)) / sigma_i(pa_i)``
   compatible with the factual evidence. If every variable is observed this is exact. If
   some are latent, a posterior over them is first inferred from the factual evidence in
   one world (:func:`inference.infer_state`), and each posterior draw is completed and
   abducted in turn.
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

K scenarios and S posterior draws run as one batch of ``K * S * N`` units, so the cost is
linear in K and S.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import pyro
import torch
from torch import Tensor

from inference.handlers import AbductNoise, Intervene, ReplayNoise
from inference.interventions import action_bounds, check_interventions
from inference.state import StateResult, infer_state, split_actions
from models.checks import check_float, check_int, check_keywords, check_mapping, check_seed, describe
from models.world import WorldModel, as_values, check_action_bounds, require_world_model

#: Keyword arguments of :func:`inference.infer_state` that ``state_kwargs`` may set.
STATE_KWARGS = (
    "measurement_scale",
    "guide",
    "num_steps",
    "lr",
    "lr_final",
    "num_particles",
    "num_samples",
    "init_scale",
    "seed",
    "progress_bar",
)

__all__ = ["STATE_KWARGS", "CounterfactualResult", "abduct", "counterfactual"]


@dataclass(frozen=True)
class CounterfactualResult:
    """Counterfactual values under each scenario.

    Attributes:
        samples: name -> ``(S, K, N, dim)``; S = 1 when the evidence was complete.
        noise: name -> ``(S, N, dim)`` abducted standardised residuals.
        exact: True when every variable was observed (no posterior was needed).
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
        q = torch.tensor([(1 - level) / 2, (1 + level) / 2])
        lo, hi = torch.quantile(self.samples[name], q, dim=0)
        return lo, hi


def abduct(
    model: WorldModel, values: Mapping[str, Tensor], n: int, interventions: Mapping[str, Any] | None = None
) -> dict[str, Tensor]:
    """Standardised residuals of every site given complete ``values`` (Eq. 4.43).

    Args:
        model: the program.
        values: name -> ``(n, dim)`` for every variable (executed actions included).
        n: number of units.
        interventions: assignments in force in the factual world (their sites get eps 0).

    Returns:
        name -> ``(n, dim)``.
    """
    model = require_world_model(model)
    n = check_int("n", n, minimum=1)
    values, _ = as_values(model.graph, values, n=n, what="values", dtype=model.dtype)
    interventions = check_interventions(
        model.graph, check_mapping("interventions", interventions, allow_none=True), model.dtype
    )
    program = Intervene(interventions)(model) if interventions else model
    # Inputs were checked by ``as_values``; Pyro's per-site argument validation only adds cost.
    with AbductNoise() as abduction, torch.no_grad(), pyro.validation_enabled(False):
        program({k: v for k, v in values.items() if not interventions or k not in interventions}, n)
    return abduction.noise


def _combine(scenarios: Sequence[Mapping[str, Any]], n: int) -> dict[str, Callable[[Tensor], Tensor]]:
    """One callable per intervened site acting block-wise on the ``(K * n, dim)`` batch.

    Tensor values are scalars, ``(dim,)`` or ``(n, dim)``; callables act on a block.
    """
    names = sorted({k for s in scenarios for k in s})
    k_total = len(scenarios)

    def site_fn(name: str) -> Callable[[Tensor], Tensor]:
        specs = [s.get(name) for s in scenarios]

        def apply(natural: Tensor) -> Tensor:
            blocks = natural.reshape(k_total, n, natural.shape[-1]).unbind(0)
            out = []
            for spec, block in zip(specs, blocks, strict=True):
                if spec is None:
                    out.append(block)
                elif callable(spec) and not isinstance(spec, Tensor):
                    new = spec(block)
                    if not isinstance(new, Tensor) or new.shape != block.shape:
                        raise ValueError(
                            f"shift intervention on {name!r} must return a tensor of shape {tuple(block.shape)}"
                        )
                    if not bool(torch.isfinite(new).all()):
                        raise ValueError(f"shift intervention on {name!r} produced NaN or inf")
                    out.append(new)
                else:
                    out.append(spec.expand_as(block))
            return torch.cat(out, 0)

        return apply

    return {name: site_fn(name) for name in names}


def _replay_descendants(
    model: WorldModel,
    factual: Mapping[str, Tensor],
    assign: Mapping[str, Callable[[Tensor], Tensor]],
    noise: Mapping[str, Tensor],
    changed: set[str],
    affected: set[str],
    k_total: int,
) -> dict[str, Tensor]:
    """Prediction step when no intervened site lies downstream of another.

    Sites outside ``affected`` (the descendants of the intervened sites) keep their
    factual values exactly, so only the affected mechanisms are evaluated:
    ``x_i = f_i(pa_i) + sigma_i(pa_i) * eps_i`` (Eq. 4.39) with the abducted ``eps_i``. The
    result equals replaying the whole intervened program.
    """
    tiled = {k: v.repeat(k_total, 1) for k, v in factual.items()}
    given = {k: v for k, v in tiled.items() if k not in affected and k not in changed}
    given.update({k: assign[k](tiled[k]) for k in changed})
    return model.predict(given, {k: noise[k] for k in affected})


def counterfactual(
    model: WorldModel,
    factual: Mapping[str, Any],
    interventions: Mapping[str, Any] | Sequence[Mapping[str, Any]],
    *,
    num_samples: int = 1000,
    seed: int = 0,
    state_kwargs: Mapping[str, Any] | None = None,
) -> CounterfactualResult:
    """What would have happened to each unit under other interventions.

    Args:
        model: the world model.
        factual: name -> ``(N, dim)`` evidence from the factual world. Executed actions
            are part of it and are treated as interventions of that world.
        interventions: one scenario (a mapping name -> value, ``(N, dim)`` tensor or
            shift callable) or a sequence of K scenarios evaluated in one batch.
        num_samples: posterior draws S when some variables are latent.
        seed: seed for the state posterior (forked RNG; the caller's RNG states are untouched).
        state_kwargs: extra arguments for :func:`inference.infer_state` (keys in
            :data:`STATE_KWARGS`).

    Returns:
        :class:`CounterfactualResult` with samples of shape ``(S, K, N, dim)``.

    Raises:
        ValueError: bad factual values (see :func:`models.world.as_values`), executed
            actions outside their bounds, bad scenarios (see :func:`inference.do`), or bad
            ``num_samples``, ``seed`` or ``state_kwargs``.
    """
    model = require_world_model(model)
    graph = model.graph
    num_samples = check_int("num_samples", num_samples, minimum=1)
    seed = check_seed("seed", seed)
    state_kwargs = check_keywords("state_kwargs", state_kwargs, STATE_KWARGS)
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
    scenarios = [check_interventions(graph, s, model.dtype) for s in scenarios]
    obs, n = as_values(graph, factual, what="factual", dtype=model.dtype)
    if n is None:
        raise ValueError("factual evidence is empty")
    check_action_bounds(graph, obs, "factual")
    for sc in scenarios:
        for name, spec in sc.items():
            if isinstance(spec, Tensor) and spec.ndim == 2 and spec.shape[0] != n:
                raise ValueError(
                    f"intervention on {name!r} has {spec.shape[0]} rows, expected {n} (one per unit)"
                )
    evidence, acts = split_actions(model, obs)
    latent = [v for v in graph.names if v not in obs]
    posterior = None
    if latent:
        kwargs = {"num_samples": num_samples, "seed": seed, **state_kwargs}
        posterior = infer_state(model, obs, **kwargs)
        s = next(iter(posterior.samples.values())).shape[0]
        world = {k: v.expand(s, *v.shape).reshape(s * n, -1) for k, v in evidence.items()}
        world.update({k: posterior.samples[k].reshape(s * n, -1) for k in latent})
    else:
        s = 1
        world = dict(evidence)
    factual_acts = {k: v.expand(s, *v.shape).reshape(s * n, -1) for k, v in acts.items()}
    noise = abduct(model, world, s * n, factual_acts)
    changed = {k for sc in scenarios for k in sc}
    # Executed actions not re-set by a scenario keep their factual values; per-unit
    # values are tiled over the S posterior draws.
    k_total = len(scenarios)
    scenarios = [
        {
            **factual_acts,
            **{k: (v.repeat(s, 1) if isinstance(v, Tensor) and v.ndim == 2 else v) for k, v in sc.items()},
        }
        for sc in scenarios
    ]
    assign = _combine(scenarios, s * n)
    tiled = {k: v.repeat(k_total, 1) for k, v in noise.items()}
    affected = set().union(*(graph.descendants(k) for k in changed))
    if affected & changed:
        # an intervened site downstream of another: its pre-intervention value must be
        # recomputed, so replay the whole intervened program
        program = Intervene(assign, bounds=action_bounds(graph, assign))(ReplayNoise(tiled)(model))
        with torch.no_grad(), pyro.validation_enabled(False):  # replayed values are ours
            values = program(None, k_total * s * n)
    else:
        values = _replay_descendants(
            model, {**world, **factual_acts}, assign, tiled, changed, affected, k_total
        )
    samples = {
        k: v.reshape(k_total, s, n, v.shape[-1]).transpose(0, 1).contiguous() for k, v in values.items()
    }
    noise_out = {k: v.reshape(s, n, v.shape[-1]) for k, v in noise.items()}
    return CounterfactualResult(samples, noise_out, exact=not latent, posterior=posterior)
