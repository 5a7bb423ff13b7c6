"""The options and result of :func:`inference.action.infer_action`, and the checks of its inputs.

:class:`ActionOptions` (preference, lr, init, sampling, horizon, risk) and :class:`ActionResult`;
and the start values.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor

from inference.action_objective import LogPreference, Risk
from inference.planning import SamplingConfig
from models.checks import describe
from models.world import WorldModel, as_values

__all__ = ["ActionOptions", "ActionResult"]


@dataclass(frozen=True)
class ActionResult:
    """Inferred actions.

    Attributes:
        actions: name -> ``(N, dim)`` optimised actions a* (within bounds); ``(N, H, dim)``
            action sequences with ``horizon=H > 1``.
        predicted: name -> ``(N, dim)`` forward query Phi(s, a*, u) for every variable
            (``(N, H, dim)``, the simulated trajectory, with a horizon); the model's own
            prediction, also when a risk weighs its ensemble members.
        losses: mean over units (and refined elites) of L_act at each Adam step, before the
            update; length ``num_steps`` (the refinement's steps with sampling); ``loss`` is an alias.
        final_loss: ``(N,)`` L_act(a*) per unit, with the risk term if any.
        search_loss: mean over units of the best candidate's loss after each sampling
            iteration (empty without sampling); never increasing.
    """

    actions: dict[str, Tensor]
    predicted: dict[str, Tensor]
    losses: tuple[float, ...]
    final_loss: Tensor
    search_loss: tuple[float, ...] = ()

    @property
    def loss(self) -> tuple[float, ...]:
        """Alias of :attr:`losses`."""
        return self.losses

    def to_dict(self) -> dict[str, Any]:
        """JSON-compatible actions, predictions and losses."""
        return {
            "actions": {k: v.tolist() for k, v in self.actions.items()},
            "predicted": {k: v.tolist() for k, v in self.predicted.items()},
            "final_loss": self.final_loss.tolist(),
            "num_steps": len(self.losses),
            "losses_last": self.losses[-1] if self.losses else None,
            "search_loss": list(self.search_loss),
        }


def _initial(
    model: WorldModel,
    names: Sequence[str],
    n: int,
    init: str | Mapping[str, Any],
    generator: torch.Generator,
    horizon: int = 1,
) -> dict[str, Tensor]:
    """Start values: name -> ``(N, dim)``, or ``(N, H, dim)`` with ``horizon=H > 1``."""
    out = {}
    if isinstance(init, Mapping):
        unknown = sorted(str(k) for k in init if k not in names)
        if unknown:
            raise ValueError(f"init names {unknown}, which are not optimised actions {list(names)}")
    elif not isinstance(init, str):
        raise ValueError(f"init must be 'midpoint', 'random' or a mapping, got {describe(init)}")
    lead = (n,) if horizon == 1 else (n, horizon)
    for name in names:
        low, high = model.bounds(name)
        dim = low.shape[0]
        if isinstance(init, Mapping):
            if name not in init:
                raise ValueError(f"init has no value for action {name!r}")
            a = _given_init(model, name, init[name], n, horizon)
            if ((a < low) | (a > high)).any():
                raise ValueError(f"init[{name!r}] lies outside the bounds [{low.tolist()}, {high.tolist()}]")
        elif init == "midpoint":
            a = ((low + high) / 2).expand(*lead, dim).clone()
        elif init == "random":
            a = low + (high - low) * torch.rand(*lead, dim, generator=generator, dtype=model.dtype)
        else:
            raise ValueError(f"init {init!r} unknown; expected 'midpoint', 'random' or a mapping")
        out[name] = a
    return out


def _given_init(model: WorldModel, name: str, raw: Any, n: int, horizon: int) -> Tensor:
    """A given start ``(N, dim)`` (held on every step) or, with a horizon, ``(N, H, dim)``."""
    if horizon > 1 and getattr(raw, "ndim", None) == 3:
        given, _ = as_values(model.graph, {name: raw}, n=n, what="init", extra_dims=1, dtype=model.dtype)
        a = given[name].detach().clone()
        if a.shape[1] != horizon:
            raise ValueError(f"init[{name!r}] has {a.shape[1]} steps, expected horizon {horizon}")
        return a
    given, _ = as_values(model.graph, {name: raw}, n=n, what="init", dtype=model.dtype)
    a = given[name].detach().clone()
    return a if horizon == 1 else a.unsqueeze(1).expand(n, horizon, a.shape[-1]).clone()


def _check_sampling(sampling: Any) -> SamplingConfig | None:
    if sampling is not None and not isinstance(sampling, SamplingConfig):
        raise ValueError(f"sampling must be None or a SamplingConfig, got {describe(sampling)}")
    return sampling


@dataclass(frozen=True)
class ActionOptions:
    """How :func:`infer_action` scores and searches actions.

    Attributes:
        scale: Gaussian preference scale > 0 (targets' units), scalar or one per target;
            also the unit of the disagreement term.
        log_preference: optional callable ``predicted -> (N,)`` log-preference replacing
            the Gaussian one (then ``targets`` may be None). With sampling, a horizon or a
            risk it gets values with leading candidate axes ``(..., N, dim)`` and must
            return ``(..., N)`` (broadcast like :func:`gaussian_log_preference`).
        lr: Adam learning rate eta_act (thesis B2: 0.05).
        init: ``"midpoint"`` (thesis B2), ``"random"`` or name -> ``(N, dim)`` within
            bounds (with a horizon also ``(N, H, dim)``).
        sampling: None (gradient only) or the sizes of the sampling stage. A model with a
            discrete site downstream of the actions gets ``SamplingConfig()`` when None:
            the argmax of a discrete site has no gradient.
        horizon: planning steps H >= 1 through the rollout (Alg. 4.1).
        target_at: with a horizon, ``"final"`` or ``"every"`` step.
        risk: None (the members' mean model), ``"mean"`` (the mean cost over the members'
            particles), ``("quantile", q)`` (their q-quantile, q > 0.5 risk averse) or
            ``("disagreement", w)`` (:mod:`inference.action_objective`).
    """

    scale: float | Mapping[str, float] = 1.0
    log_preference: LogPreference | None = None
    lr: float = 0.05
    init: str | Mapping[str, Any] = "midpoint"
    sampling: SamplingConfig | None = None
    horizon: int = 1
    target_at: str = "final"
    risk: Risk = None
