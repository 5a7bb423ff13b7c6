"""Variational state inference (thesis Eq. 4.41-4.42).

    q* = argmin_q  E_q[ log q(x_lat) - log p_M(x_obs, x_lat) ]

over the latent sites, i.e. every variable that is neither observed nor intervened on,
with SVI and an AutoNormal (default) or AutoMultivariateNormal guide. Each unit of the
plate gets its own posterior.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import pyro
import pyro.distributions as dist
import torch
from pyro.infer import SVI, Trace_ELBO
from pyro.infer.autoguide import AutoMultivariateNormal, AutoNormal
from pyro.optim import ClippedAdam
from torch import Tensor
from tqdm import tqdm

from inference.frozen import frozen_parameters
from inference.handlers import Intervene, MeasurementScale
from inference.interventions import check_interventions
from models.checks import (
    as_float_tensor,
    check_bool,
    check_callable,
    check_choice,
    check_float,
    check_int,
    check_mapping,
    check_seed,
    describe,
)
from models.graph import CausalGraph
from models.variables import Role
from models.world import WorldModel, as_values, check_action_bounds, model_dtype

__all__ = ["GUIDES", "StateResult", "infer_state"]

log = logging.getLogger(__name__)

GUIDES = {"normal": AutoNormal, "mvn": AutoMultivariateNormal}

_Z1 = 0.8413447460685429  # Phi(1): (q(Phi(1)) - q(Phi(-1))) / 2 is the sd of a Normal marginal


@dataclass(frozen=True)
class StateResult:
    """Posterior over latent sites.

    Attributes:
        latent: names of the inferred sites.
        mean, sd: name -> ``(N, dim)`` posterior mean and standard deviation; exact for
            the variational family on unconstrained sites, Monte Carlo otherwise.
        samples: name -> ``(S, N, dim)`` posterior draws.
        loss: -ELBO per unit at every SVI step.
        guide: the fitted autoguide.
        param_state: its parameters (``pyro.get_param_store().scope(param_state)``
            restores them for further use of ``guide``).
    """

    latent: tuple[str, ...]
    mean: dict[str, Tensor]
    sd: dict[str, Tensor]
    samples: dict[str, Tensor]
    loss: tuple[float, ...]
    guide: Any = field(repr=False)
    param_state: dict[str, Any] = field(repr=False)

    def interval(self, name: str, level: float = 0.9) -> tuple[Tensor, Tensor]:
        """Equal-tailed credible interval from the samples: two ``(N, dim)`` tensors."""
        level = check_float("level", level, minimum=0.0, maximum=1.0, min_open=True, max_open=True)
        if not isinstance(name, str) or name not in self.samples:
            raise ValueError(f"{name!r} is not a latent site; latent: {list(self.latent)}")
        q = torch.tensor([(1 - level) / 2, (1 + level) / 2])
        lo, hi = torch.quantile(self.samples[name], q, dim=0)
        return lo, hi


def split_actions(
    model: WorldModel, observed: Mapping[str, Tensor]
) -> tuple[dict[str, Tensor], dict[str, Tensor]]:
    """Separate executed actions (applied as do, Eq. 4.30) from observed evidence: ``(evidence, actions)``."""
    acts = {k: v for k, v in observed.items() if model.graph[k].role is Role.ACTION}
    evidence = {k: v for k, v in observed.items() if k not in acts}
    return evidence, acts


def infer_state(
    model: WorldModel,
    observed: Mapping[str, Any],
    *,
    interventions: Mapping[str, Any] | None = None,
    measurement_scale: Mapping[str, Tensor] | None = None,
    guide: str = "normal",
    num_steps: int = 500,
    lr: float = 0.1,
    lr_final: float = 0.001,
    num_particles: int = 16,
    num_samples: int = 1000,
    init_scale: float = 0.1,
    seed: int = 0,
    progress_bar: bool = False,
) -> StateResult:
    """SVI posterior over the latent sites given the observed sites.

    Args:
        model: the world model (any Pyro program with a ``graph`` following the
            :class:`models.WorldModel` call contract works).
        observed: name -> ``(N, dim)`` evidence. Executed actions in it are applied as
            ``do(action)``, not conditioned on.
        interventions: extra ``do`` assignments (see :func:`inference.do`).
        measurement_scale: observed measurement site -> per-unit sigma ``(N, dim)`` or
            ``(dim,)`` replacing its learned sigma (:class:`inference.MeasurementScale`),
            e.g. the uncertainty perception reports for each frame.
        guide: ``"normal"`` (AutoNormal, mean field) or ``"mvn"`` (AutoMultivariateNormal).
        num_steps: ClippedAdam steps.
        lr: initial ClippedAdam learning rate.
        lr_final: learning rate at the last step (geometric decay from ``lr``).
        num_particles: vectorised ELBO particles per step.
        num_samples: posterior draws S returned in ``samples``.
        init_scale: initial guide scale, > 0.
        seed: seeds Pyro's sampling (torch's RNG) inside a forked RNG context; the
            caller's torch, numpy and Python RNG states are left as they were.
        progress_bar: show a tqdm bar.

    Returns:
        :class:`StateResult`.

    Raises:
        ValueError: bad evidence (see :func:`models.world.as_values`), executed actions
            outside their bounds, bad interventions or measurement scales, or a bad
            optimiser argument (type or range).
        FloatingPointError: the ELBO became NaN or inf.
    """
    check_callable("model", model)
    graph = getattr(model, "graph", None)
    if not isinstance(graph, CausalGraph):
        raise ValueError(
            f"model must be a WorldModel (or a program with a CausalGraph `graph`), got {describe(model)}"
        )
    guide = check_choice("guide", guide, sorted(GUIDES))
    num_steps = check_int("num_steps", num_steps, minimum=1)
    num_particles = check_int("num_particles", num_particles, minimum=1)
    num_samples = check_int("num_samples", num_samples, minimum=1)
    lr = check_float("lr", lr, minimum=0.0, min_open=True)
    lr_final = check_float("lr_final", lr_final, minimum=0.0, min_open=True)
    init_scale = check_float("init_scale", init_scale, minimum=0.0, min_open=True)
    seed = check_seed("seed", seed)
    progress_bar = check_bool("progress_bar", progress_bar)
    dtype = model_dtype(model)
    obs, n = as_values(graph, observed, what="observed", dtype=dtype)
    if n is None:
        raise ValueError("observed is empty; state inference needs evidence")
    check_action_bounds(graph, obs, "observed")
    evidence, acts = split_actions(model, obs)
    ivs = {
        **acts,
        **check_interventions(graph, check_mapping("interventions", interventions, allow_none=True), dtype),
    }
    both = sorted(set(evidence) & set(ivs))
    if both:
        raise ValueError(f"variables {both} are both observed and intervened on; pick one")
    latent = tuple(v for v in graph.topological_order() if v not in evidence and v not in ivs)
    if not latent:
        raise ValueError("every variable is observed or intervened on; there is no latent site to infer")
    program = Intervene(ivs)(model) if ivs else model
    measurement_scale = check_mapping("measurement_scale", measurement_scale, allow_none=True)
    if measurement_scale:
        scales = {}
        for name, raw in measurement_scale.items():
            graph.check_name(name, what="measurement site")
            scale = as_float_tensor(raw, f"measurement_scale[{name!r}]", dtype)
            if scale.ndim not in (1, 2) or scale.shape[-1] != graph[name].dim:
                raise ValueError(
                    f"measurement_scale[{name!r}] has shape {tuple(scale.shape)}, expected (dim,) or "
                    f"(N, dim), here ({graph[name].dim},) or ({n}, {graph[name].dim})"
                )
            if scale.ndim == 2 and scale.shape[0] != n:
                raise ValueError(f"measurement_scale[{name!r}] has {scale.shape[0]} rows, expected {n}")
            scales[name] = scale
        unobserved = sorted(set(scales) - set(evidence))
        if unobserved:
            raise ValueError(f"measurement_scale names {unobserved}, which are not observed sites")
        program = MeasurementScale(scales)(program)

    param_store = pyro.get_param_store()
    # Pyro samples with torch's global RNG: fork it and seed inside, so the caller's
    # state is restored afterwards (numpy's and Python's RNGs are never used).
    with param_store.scope() as param_state, torch.random.fork_rng(), frozen_parameters(model):
        torch.manual_seed(seed)
        auto = GUIDES[guide](program, init_scale=init_scale)
        optim = ClippedAdam({"lr": lr, "lrd": (lr_final / lr) ** (1.0 / num_steps)})
        elbo = Trace_ELBO(
            num_particles=num_particles, vectorize_particles=num_particles > 1, max_plate_nesting=1
        )
        svi = SVI(program, auto, optim, elbo)
        losses: list[float] = []
        bar = tqdm(range(num_steps), desc="infer_state", disable=not progress_bar, leave=False)
        for _ in bar:
            loss = svi.step(evidence, n) / n
            if not math.isfinite(loss):
                raise FloatingPointError(
                    f"ELBO became {loss} at step {len(losses)}; check that the evidence lies in the "
                    "support of the model (e.g. within action bounds) or lower lr"
                )
            losses.append(loss)
            if len(losses) % 50 == 0:
                bar.set_postfix(loss=f"{loss:.4g}")
        with torch.no_grad():
            with pyro.plate("_posterior_samples", num_samples, dim=-2):
                trace = pyro.poutine.trace(auto).get_trace(evidence, n)
            samples = {k: trace.nodes[k]["value"].detach() for k in latent}
            median = auto.median(evidence, n)
            quant = auto.quantiles([1 - _Z1, _Z1], evidence, n)
        mean, sd = {}, {}
        for k in latent:
            if _support_is_real(auto.prototype_trace.nodes[k]["fn"].support):
                mean[k] = median[k].detach()
                lo, hi = quant[k].detach()
                sd[k] = (hi - lo) / 2
            else:
                mean[k] = samples[k].mean(0)
                sd[k] = samples[k].std(0)
    log.debug("infer_state: %d steps, final loss %.4g", num_steps, losses[-1])
    return StateResult(latent, mean, sd, samples, tuple(losses), auto, param_state)


def _support_is_real(support: Any) -> bool:
    base = support
    while hasattr(base, "base_constraint"):
        base = base.base_constraint
    return base is dist.constraints.real
