"""Gradient-based action inference through do(action) (thesis Eq. 4.45-4.49, Alg. 4.2).

    L_act(a) = -log p(Phi(s, a, u) | C)
    a <- clip(a - eta * Adam(grad_a L_act), A)          for K_act steps

Phi is the forward query: the program under ``do(actions = a)`` with the state given and
residuals replayed (expected residuals by default, or abducted ones). The world-model
parameters stay fixed. Every (state, target) unit is optimised at once; the loss is a sum
over units, so each unit's actions follow their own Adam trajectory.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor
from tqdm import tqdm

from inference.frozen import frozen_parameters
from inference.handlers import Intervene, ReplayNoise
from models.variables import Role
from models.world import WorldModel, as_values

__all__ = ["ActionResult", "gaussian_log_preference", "infer_action"]

log = logging.getLogger(__name__)

LogPreference = Callable[[Mapping[str, Tensor]], Tensor]


@dataclass(frozen=True)
class ActionResult:
    """Inferred actions.

    Attributes:
        actions: name -> ``(N, dim)`` optimised actions a* (within bounds).
        predicted: name -> ``(N, dim)`` forward query Phi(s, a*, u) for every variable.
        loss: mean over units of L_act at each step (before the update), length ``steps``.
        final_loss: ``(N,)`` L_act(a*) per unit.
    """

    actions: dict[str, Tensor]
    predicted: dict[str, Tensor]
    loss: tuple[float, ...]
    final_loss: Tensor


def gaussian_log_preference(
    targets: Mapping[str, Tensor], scale: float | Mapping[str, float] = 1.0
) -> LogPreference:
    """log p(x_tar | C) = sum_i log N(x_i; target_i, scale_i^2), per unit (Eq. 4.45).

    With a common scale this is, up to constants, ``-MSE / (2 scale^2)``.
    """

    def log_pref(pred: Mapping[str, Tensor]) -> Tensor:
        total = 0.0
        for name, target in targets.items():
            s = scale[name] if isinstance(scale, Mapping) else scale
            total = total - (0.5 * ((pred[name] - target) / s) ** 2).sum(-1)
        return total

    return log_pref


def _initial(
    model: WorldModel, names: Sequence[str], n: int, init: str | Mapping[str, Any], generator: torch.Generator
) -> dict[str, Tensor]:
    out = {}
    for name in names:
        low, high = model.bounds(name)
        dim = low.shape[0]
        if isinstance(init, Mapping):
            if name not in init:
                raise ValueError(f"init has no value for action {name!r}")
            given, _ = as_values(model.graph, {name: init[name]}, n=n, what="init")
            a = given[name].clone()
            if ((a < low) | (a > high)).any():
                raise ValueError(f"init[{name!r}] lies outside the bounds [{low.tolist()}, {high.tolist()}]")
        elif init == "midpoint":
            a = ((low + high) / 2).expand(n, dim).clone()
        elif init == "random":
            a = low + (high - low) * torch.rand(n, dim, generator=generator)
        else:
            raise ValueError(f"init {init!r} unknown; expected 'midpoint', 'random' or a mapping")
        out[name] = a
    return out


def infer_action(
    model: WorldModel,
    state: Mapping[str, Any] | None,
    targets: Mapping[str, Any] | None = None,
    *,
    actions: Sequence[str] | None = None,
    log_preference: LogPreference | None = None,
    scale: float | Mapping[str, float] = 1.0,
    steps: int = 200,
    lr: float = 0.05,
    init: str | Mapping[str, Any] = "midpoint",
    noise: Mapping[str, Any] | None = None,
    seed: int = 0,
    progress_bar: bool = False,
) -> ActionResult:
    """Find actions whose predicted consequences match the targets (Alg. 4.2).

    Args:
        model: the world model (fixed).
        state: name -> ``(N, dim)`` current state estimate s(t) (e.g. ``q_prev``), and
            any actions that are held fixed; None if the graph has no other roots.
        targets: name -> ``(N, dim)`` desired values; with the default Gaussian
            preference the loss is ``sum 0.5 ((Phi - target) / scale)^2``.
        actions: action variables to optimise (default: every action not in ``state``).
        log_preference: optional callable ``predicted -> (N,)`` log-preference replacing
            the Gaussian one (then ``targets`` may be None).
        scale: Gaussian preference scale, scalar or per target.
        steps, lr: Adam iterations K_act and learning rate eta_act (thesis B2: 200, 0.05).
        init: ``"midpoint"`` (thesis B2), ``"random"`` or name -> ``(N, dim)``.
        noise: name -> ``(N, dim)`` standardised residuals u (e.g. abducted); default:
            expected residuals u-bar (Alg. 4.2).
        seed: seed for ``init="random"``.
        progress_bar: show a tqdm bar.

    Returns:
        :class:`ActionResult`.
    """
    graph = model.graph
    if not isinstance(steps, int) or steps < 1:
        raise ValueError(f"steps must be a positive int, got {steps!r}")
    if not lr > 0:
        raise ValueError(f"lr must be > 0, got {lr}")
    given, n = as_values(graph, state, what="state")
    tgt, n = as_values(graph, targets or {}, n=n, what="targets")
    if n is None:
        raise ValueError("state and targets are empty; cannot tell the number of units")
    if actions is None:
        actions = [a for a in graph.actions if a not in given]
    actions = list(actions)
    for a in actions:
        graph.check_name(a, what="action")
        if graph[a].role is not Role.ACTION:
            raise ValueError(f"{a!r} has role {graph[a].role.value!r}; only actions can be optimised")
        if a in given:
            raise ValueError(f"action {a!r} is both given in state and optimised")
    if not actions:
        raise ValueError("no action to optimise: the graph has no actions, or all are given in state")
    for name in tgt:
        if name in actions:
            raise ValueError(f"target {name!r} is an optimised action; targets must be consequences")
    if log_preference is None:
        if not tgt:
            raise ValueError("give targets or a log_preference")
        log_preference = gaussian_log_preference(tgt, scale)
    fixed_acts = {k: v for k, v in given.items() if graph[k].role is Role.ACTION}
    evidence = {k: v for k, v in given.items() if k not in fixed_acts}
    eps, _ = as_values(graph, noise or {}, n=n, what="noise")

    generator = torch.Generator().manual_seed(seed)
    params = {k: v.requires_grad_(True) for k, v in _initial(model, actions, n, init, generator).items()}
    bounds = {k: model.bounds(k) for k in actions}
    optim = torch.optim.Adam(list(params.values()), lr=lr)

    def forward() -> dict[str, Tensor]:
        program = Intervene({**fixed_acts, **params})(ReplayNoise(eps, default="expected")(model))
        return program(evidence, n)

    history: list[float] = []
    with frozen_parameters(model):
        for _ in tqdm(range(steps), desc="infer_action", disable=not progress_bar, leave=False):
            optim.zero_grad()
            per_unit = -log_preference(forward())
            if per_unit.shape != (n,):
                raise ValueError(f"log_preference returned shape {tuple(per_unit.shape)}, expected ({n},)")
            loss = per_unit.sum()
            loss.backward()
            optim.step()
            with torch.no_grad():
                for k, p in params.items():
                    p.copy_(torch.clamp(p, *bounds[k]))
            history.append(float(loss.detach()) / n)
        with torch.no_grad():
            predicted = forward()
            final = -log_preference(predicted)
    if not torch.isfinite(final).all():
        raise FloatingPointError("action inference produced a non-finite loss; check targets and scales")
    acts = {k: v.detach().clone() for k, v in params.items()}
    return ActionResult(acts, {k: v.detach() for k, v in predicted.items()}, tuple(history), final.detach())
