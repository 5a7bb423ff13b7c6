"""The torch fast path of :func:`inference.counterfactual` on a plain :class:`models.WorldModel`.

Abduction runs once per unit (and per posterior draw when some sites are latent); the K
scenarios are then one batched replay of ``K * N`` rows in which only the descendants of
each scenario's interventions are recomputed,

    x_i' = f_i(pa_i') + sigma_i(pa_i') * eps_i        (Eq. 4.39, 4.43),

while every other site keeps its factual value. Sites that no scenario reaches are copied.

Discrete sites are Gumbel-max SCMs (:mod:`models.discrete`). When every variable is observed,
only the discrete sites that some scenario recomputes without setting them ("uncertain")
carry uncertainty: their S Gumbel posterior draws are made for them alone, the sites upstream
of them and beside them are replayed once (``K * N`` rows), and only they and their
descendants are replayed ``S * K * N`` times.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import pyro
import torch
from torch import Tensor

from inference.abduction import _abduct, _abduct_plain, _torch_abduction
from inference.handlers import Intervene, ReplayNoise
from inference.interventions import action_bounds
from inference.program import Program
from inference.state import StateResult
from models.discrete import gumbel_posterior
from models.world import WorldModel, check_action_bounds


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
            return torch.cat(
                [_apply(name, spec, block) for spec, block in zip(specs, blocks, strict=True)], 0
            )

        return apply

    return {name: site_fn(name) for name in names}


def _apply(name: str, spec: Any, block: Tensor) -> Tensor:
    """One scenario's assignment on its block of the batch (``None``: no intervention)."""
    if spec is None:
        return block
    if callable(spec) and not isinstance(spec, Tensor):
        new = spec(block)
        if not isinstance(new, Tensor) or new.shape != block.shape:
            raise ValueError(
                f"shift intervention on {name!r} must return a tensor of shape {tuple(block.shape)}"
            )
        if not bool(torch.isfinite(new).all()):
            raise ValueError(f"shift intervention on {name!r} produced NaN or inf")
        return new
    return spec.expand_as(block)


def _stacked(scenarios: Sequence[Mapping[str, Any]]) -> dict[str, Callable[[Tensor], Tensor]]:
    """One callable per intervened site acting on a ``(K, S, N, dim)`` batch (scenario axis first)."""
    names = sorted({k for s in scenarios for k in s})

    def site_fn(name: str) -> Callable[[Tensor], Tensor]:
        specs = [s.get(name) for s in scenarios]

        def apply(natural: Tensor) -> Tensor:
            while natural.ndim < 4:  # (N, dim) or (S, N, dim) of a site the plates broadcast later
                natural = natural.unsqueeze(0)
            blocks = natural.expand(len(specs), *natural.shape[1:]).unbind(0)
            return torch.stack([_apply(name, spec, block) for spec, block in zip(specs, blocks, strict=True)])

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
    assigned = {k: assign[k](tiled[k]) for k in changed}
    # the factual values, the abducted noise and the scenarios were checked once; only the
    # assigned values (shift callables) can still break an action bound or a category code
    check_action_bounds(model.graph, assigned, "interventions")
    model.check_codes(assigned, "interventions")
    with torch.no_grad():
        return model._predict({**given, **assigned}, {k: noise[k] for k in affected}, None)


def _fast(
    model: WorldModel,
    evidence: Mapping[str, Tensor],
    acts: Mapping[str, Tensor],
    state: StateResult | None,
    latent: tuple[str, ...],
    scenarios: list[dict[str, Any]],
    uncertain: set[str],
    s: int,
    n: int,
    generator: torch.Generator,
) -> tuple[dict[str, Tensor], dict[str, Tensor]]:
    """A plain model: abduction once, the scenarios' descendants replayed in one batch.

    ``uncertain`` are the discrete sites whose Gumbel draws matter. With no latent site, the
    S draws are made for them alone (module docstring); with latent sites every row is
    repeated over the S posterior draws.

    Returns:
        samples name -> ``(S, K, N, dim)`` and noise name -> ``(S, N, dim)``.
    """
    graph = model.graph
    k_total = len(scenarios)
    changed = {k for sc in scenarios for k in sc}
    affected = set().union(*(graph.descendants(k) for k in changed))
    if state is None and not (affected & changed):
        return _fast_observed(model, {**evidence, **acts}, acts, scenarios, uncertain, s, n, generator)
    world = {k: v.expand(s, *v.shape).reshape(s * n, -1) for k, v in evidence.items()}
    if state is not None:
        world.update({k: state.samples[k].reshape(s * n, -1) for k in latent})
    factual_acts = {k: v.expand(s, *v.shape).reshape(s * n, -1) for k, v in acts.items()}
    noise = _abduction(model, {**world, **factual_acts}, factual_acts, s * n, generator)
    assign = _combine(_with_acts(scenarios, factual_acts, s), s * n)
    tiled = {k: v.repeat(k_total, 1) for k, v in noise.items()}
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
    return samples, noise_out


def _with_acts(
    scenarios: Sequence[Mapping[str, Any]], acts: Mapping[str, Tensor], s: int
) -> list[dict[str, Any]]:
    """Each scenario over the executed actions it does not re-set; per-unit values tiled over S."""
    return [
        {
            **acts,
            **{k: (v.repeat(s, 1) if isinstance(v, Tensor) and v.ndim == 2 else v) for k, v in sc.items()},
        }
        for sc in scenarios
    ]


def _abduction(
    model: WorldModel,
    values: Mapping[str, Tensor],
    acts: Mapping[str, Tensor],
    rows: int,
    generator: torch.Generator,
) -> dict[str, Tensor]:
    """Standardised residuals (one Gumbel posterior draw per discrete site) of ``rows`` complete rows."""
    if _torch_abduction(model, acts):
        return _abduct_plain(model, values, acts)
    return _abduct(Program(model), values, rows, acts, generator)


def _fast_observed(
    model: WorldModel,
    obs: Mapping[str, Tensor],
    acts: Mapping[str, Tensor],
    scenarios: list[dict[str, Any]],
    uncertain: set[str],
    s: int,
    n: int,
    generator: torch.Generator,
) -> tuple[dict[str, Tensor], dict[str, Tensor]]:
    """Every variable observed: one abduction of N rows, S Gumbel draws for ``uncertain`` only.

    The affected sites are replayed once on ``K * N`` rows; the uncertain discrete sites and
    their descendants are replayed again on ``S * K * N`` rows with their S draws, the other
    sites given (module docstring). Without uncertain sites S is 1.
    """
    graph = model.graph
    k_total = len(scenarios)
    changed = {k for sc in scenarios for k in sc}
    affected = set().union(*(graph.descendants(k) for k in changed))
    noise = _abduction(model, obs, acts, n, generator)
    draws = {}
    for name in uncertain:  # (S, N, K) posterior Gumbels given the observed code
        logits = model.mechanism(name).logits(model._parents(name, obs))
        draws[name] = gumbel_posterior(logits.expand(s, *logits.shape), obs[name], generator)
    assign = _combine(_with_acts(scenarios, acts, 1), n)
    tiled = {k: v.repeat(k_total, 1) for k, v in noise.items()}
    once = _replay_descendants(model, obs, assign, tiled, changed, affected, k_total)
    samples = {k: v.reshape(1, k_total, n, v.shape[-1]) for k, v in once.items()}
    if uncertain:
        below = (uncertain | set().union(*(graph.descendants(d) for d in uncertain))) - changed
        rows = s * k_total * n
        given = {k: v.expand(s, *v.shape).reshape(rows, -1) for k, v in once.items() if k not in below}
        eps = {k: noise[k].expand(s, k_total, *noise[k].shape).reshape(rows, -1) for k in below - uncertain}
        for name, g in draws.items():
            eps[name] = g.unsqueeze(1).expand(s, k_total, n, g.shape[-1]).reshape(rows, -1)
        with torch.no_grad():
            again = model.predict(given, eps)
        samples = {k: v.expand(s, *v.shape[1:]) for k, v in samples.items()}
        samples.update({k: again[k].reshape(s, k_total, n, -1) for k in below})
        noise = {**noise, **{k: v for k, v in draws.items()}}
    noise_out = {k: (v if v.ndim == 3 else v.expand(s, *v.shape)) for k, v in noise.items()}
    return {k: v.contiguous() for k, v in samples.items()}, noise_out
