"""The torch fast path of :func:`inference.counterfactual` on a plain :class:`models.WorldModel`.

Abduction runs once per unit (and per posterior draw when some sites are latent). The K
scenarios are then stacked on a leading batch axis and replayed in one pass over the sites in
topological order. Scenario k recomputes only the descendants of its own interventions,

    x_i' = f_i(pa_i') + sigma_i(pa_i') * eps_i        (Eq. 4.39, 4.43),

and every other site keeps its factual ``(N, dim)`` value, broadcast over the scenarios and
never tiled: the shared ancestors and the abduction cost nothing per scenario. A site is
evaluated once for all the scenarios that recompute it, on their ``(K', N)`` rows. An
intervened site that descends from another intervention takes its assignment on its
recomputed natural value (a shift callable sees that value), as the intervened program does.

Discrete sites are Gumbel-max SCMs (:mod:`models.discrete`). When every variable is observed,
only the discrete sites that some scenario recomputes without setting them ("uncertain")
carry uncertainty: their S Gumbel posterior draws are made for them alone, the sites upstream
of them and beside them are replayed once (``K * N`` rows), and only they and their
descendants are replayed ``S * K * N`` times.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import torch
from torch import Tensor

from inference.abduction import _abduct, _abduct_plain, _torch_abduction
from inference.program import Program
from inference.state import StateResult
from models.discrete import gumbel_max, gumbel_posterior
from models.folded import loc_scale
from models.world import WorldModel, check_action_bounds


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
    scenarios: Sequence[Mapping[str, Any]],
    noise: Mapping[str, Tensor],
) -> dict[str, Tensor]:
    """Prediction step of K scenarios stacked on a leading batch axis: name -> ``(K, N, dim)``.

    Scenario k recomputes only the descendants of its own interventions,
    ``x_i = f_i(pa_i) + sigma_i(pa_i) * eps_i`` (Eq. 4.39) with the abducted ``eps_i``
    (``(N, dim)``, broadcast over K; a discrete site takes ``argmax(l(pa) + g)``); every other
    site keeps its factual ``(N, dim)`` value, which is broadcast over K and never tiled. A
    site is evaluated once for all the scenarios that recompute it, on their rows only, so
    the shared ancestors cost nothing per scenario. An intervened site takes its assignment,
    a shift callable acting on the site's natural value in that scenario. The result equals
    replaying the whole intervened program with the same residuals (tests hold them equal).

    Sites that no scenario changes are returned as expanded views of the factual values.
    """
    graph = model.graph
    k_total = len(scenarios)
    below = [set().union(*(graph.descendants(v) for v in sc)) if sc else set() for sc in scenarios]
    stacked: dict[str, Tensor] = {}  # sites some scenario changes: (K, N, dim)
    for name in graph.topological_order():
        rows = [k for k in range(k_total) if name in below[k]]
        if not rows and not any(name in sc for sc in scenarios):
            continue
        natural = _natural(model, name, rows, factual, stacked, noise, k_total)
        blocks = [natural[k] for k in range(k_total)]
        assigned = [k for k in range(k_total) if name in scenarios[k]]
        for k in assigned:
            blocks[k] = _apply(name, scenarios[k][name], blocks[k])
        value = torch.stack(blocks) if assigned else natural
        if any(callable(scenarios[k][name]) and not isinstance(scenarios[k][name], Tensor) for k in assigned):
            # the values and the scenarios were checked once; a shift callable's output can
            # still break an action bound or a category code
            flat = {name: value.reshape(-1, value.shape[-1])}
            check_action_bounds(graph, flat, "interventions")
            model.check_codes(flat, "interventions")
        stacked[name] = value
    return {k: stacked[k] if k in stacked else v.expand(k_total, *v.shape) for k, v in factual.items()}


def _natural(
    model: WorldModel,
    name: str,
    rows: list[int],
    factual: Mapping[str, Tensor],
    stacked: Mapping[str, Tensor],
    noise: Mapping[str, Tensor],
    k_total: int,
) -> Tensor:
    """``(K, N, dim)`` natural values of ``name``: its mechanism replayed on the scenarios ``rows``, factual elsewhere."""
    fact = factual[name].expand(k_total, *factual[name].shape)
    if not rows:
        return fact
    every = len(rows) == k_total
    index = None if every else torch.tensor(rows)
    parents = {}
    for p in model.graph.parents(name):
        value = stacked.get(p)
        parents[p] = factual[p] if value is None else (value if every else value.index_select(0, index))
    pa = model._parents(name, parents)
    if pa.ndim == 2:  # no parent changed in these scenarios (cannot happen below an intervention)
        pa = pa.expand(len(rows), *pa.shape)
    mech = model.mechanism(name)
    if name in model.discrete:
        replayed = gumbel_max(_chunked(mech.logits, pa)[0], noise[name])
    else:
        loc, scale = _chunked(loc_scale(mech, pa.shape[0] * pa.shape[1]), pa)
        replayed = loc + scale * noise[name]
    if every:
        return replayed
    return fact.clone().index_copy_(0, index, replayed)


#: rows per mechanism call in the batched replay: larger batches make the ``(rows, hidden)``
#: intermediates of an MLP outgrow the CPU caches and the allocator's reuse, and run up to
#: about 3x slower per row (32 000 rows against 8 000, one torch thread)
CHUNK_ROWS = 8192


def _chunked(fn: Callable[[Tensor], Any], pa: Tensor) -> tuple[Tensor, ...]:
    """``fn`` on ``(R, N, in)`` parents in row chunks of at most ``CHUNK_ROWS``; outputs ``(R, N, out)``."""
    r, n = pa.shape[0], pa.shape[1]
    if r * n <= CHUNK_ROWS:
        out = fn(pa)
        return out if isinstance(out, tuple) else (out,)
    flat = pa.reshape(r * n, pa.shape[-1])
    parts = [fn(chunk) for chunk in flat.split(CHUNK_ROWS)]
    parts = [p if isinstance(p, tuple) else (p,) for p in parts]
    return tuple(torch.cat([p[i] for p in parts]).reshape(r, n, -1) for i in range(len(parts[0])))


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
    k_total = len(scenarios)
    if state is None and not (uncertain and _nested(model.graph, scenarios)):
        return _fast_observed(model, {**evidence, **acts}, acts, scenarios, uncertain, s, n, generator)
    world = {k: v.expand(s, *v.shape).reshape(s * n, -1) for k, v in evidence.items()}
    if state is not None:
        world.update({k: state.samples[k].reshape(s * n, -1) for k in latent})
    factual_acts = {k: v.expand(s, *v.shape).reshape(s * n, -1) for k, v in acts.items()}
    noise = _abduction(model, {**world, **factual_acts}, factual_acts, s * n, generator)
    with torch.no_grad():
        values = _replay_descendants(model, {**world, **factual_acts}, _tiled_specs(scenarios, s), noise)
    samples = {
        k: v.reshape(k_total, s, n, v.shape[-1]).transpose(0, 1).contiguous() for k, v in values.items()
    }
    noise_out = {k: v.reshape(s, n, v.shape[-1]) for k, v in noise.items()}
    return samples, noise_out


def _nested(graph: Any, scenarios: Sequence[Mapping[str, Any]]) -> bool:
    """Whether some intervened site descends from an intervention (of any scenario)."""
    changed = {k for sc in scenarios for k in sc}
    return bool(changed & set().union(*(graph.descendants(k) for k in changed)))


def _tiled_specs(scenarios: Sequence[Mapping[str, Any]], s: int) -> list[dict[str, Any]]:
    """Each scenario with its per-unit ``(N, dim)`` values tiled over the S draws (``(S * N, dim)``)."""
    if s == 1:
        return [dict(sc) for sc in scenarios]
    return [
        {k: (v.repeat(s, 1) if isinstance(v, Tensor) and v.ndim == 2 else v) for k, v in sc.items()}
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
    noise = _abduction(model, obs, acts, n, generator)
    draws = {}
    for name in uncertain:  # (S, N, K) posterior Gumbels given the observed code
        logits = model.mechanism(name).logits(model._parents(name, obs))
        draws[name] = gumbel_posterior(logits.expand(s, *logits.shape), obs[name], generator)
    with torch.no_grad():
        once = _replay_descendants(model, obs, scenarios, noise)  # name -> (K, N, dim)
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
