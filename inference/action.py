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
from models.checks import (
    as_float_tensor,
    check_bool,
    check_callable,
    check_finite_tensor,
    check_float,
    check_int,
    check_mapping,
    check_names,
    check_seed,
    describe,
)
from models.variables import Role
from models.world import WorldModel, as_values, check_action_bounds, require_world_model

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


def _scales(scale: float | Mapping[str, float], names: Sequence[str]) -> dict[str, float]:
    """One finite scale > 0 per target name (a scalar applies to all)."""
    if isinstance(scale, Mapping):
        unknown = sorted(str(k) for k in scale if k not in names)
        missing = [k for k in names if k not in scale]
        if unknown or missing:
            raise ValueError(
                f"scale must give one value per target; unknown names {unknown}, missing {missing}"
            )
        return {k: check_float(f"scale[{k!r}]", scale[k], minimum=0.0, min_open=True) for k in names}
    s = check_float("scale", scale, minimum=0.0, min_open=True)
    return dict.fromkeys(names, s)


def gaussian_log_preference(
    targets: Mapping[str, Tensor], scale: float | Mapping[str, float] = 1.0
) -> LogPreference:
    """Gaussian log-preference around the targets (Eq. 4.45).

    Per unit, ``log p(x_tar | C) = sum_i -0.5 ((x_i - target_i) / scale_i)^2``. Up to
    constants this is ``sum_i log N(x_i; target_i, scale_i^2)``; with a common scale it is
    ``-SSE / (2 scale^2)``.

    Args:
        targets: name -> ``(N, dim)`` finite target values.
        scale: finite scale > 0 in the targets' units, one for all or name -> scale.

    Returns:
        A callable ``predicted -> (N,)``.
    """
    targets = check_mapping("targets", targets)
    if not targets:
        raise ValueError("targets is empty; give name -> (N, dim) target values")
    tgt = {}
    for name, value in targets.items():
        if not isinstance(name, str):
            raise ValueError(f"target names must be str, got {describe(name)}")
        tgt[name] = check_finite_tensor(f"targets[{name!r}]", as_float_tensor(value, f"targets[{name!r}]"))
    scales = _scales(scale, list(tgt))

    def log_pref(pred: Mapping[str, Tensor]) -> Tensor:
        missing = [k for k in tgt if k not in pred]
        if missing:
            raise ValueError(f"predicted values have no {missing}; the targets name them")
        total = 0.0
        for name, target in tgt.items():
            total = total - (0.5 * ((pred[name] - target) / scales[name]) ** 2).sum(-1)
        return total

    return log_pref


def _initial(
    model: WorldModel, names: Sequence[str], n: int, init: str | Mapping[str, Any], generator: torch.Generator
) -> dict[str, Tensor]:
    out = {}
    if isinstance(init, Mapping):
        unknown = sorted(str(k) for k in init if k not in names)
        if unknown:
            raise ValueError(f"init names {unknown}, which are not optimised actions {list(names)}")
    elif not isinstance(init, str):
        raise ValueError(f"init must be 'midpoint', 'random' or a mapping, got {describe(init)}")
    for name in names:
        low, high = model.bounds(name)
        dim = low.shape[0]
        if isinstance(init, Mapping):
            if name not in init:
                raise ValueError(f"init has no value for action {name!r}")
            given, _ = as_values(model.graph, {name: init[name]}, n=n, what="init", dtype=model.dtype)
            a = given[name].detach().clone()
            if ((a < low) | (a > high)).any():
                raise ValueError(f"init[{name!r}] lies outside the bounds [{low.tolist()}, {high.tolist()}]")
        elif init == "midpoint":
            a = ((low + high) / 2).expand(n, dim).clone()
        elif init == "random":
            a = low + (high - low) * torch.rand(n, dim, generator=generator, dtype=model.dtype)
        else:
            raise ValueError(f"init {init!r} unknown; expected 'midpoint', 'random' or a mapping")
        out[name] = a
    return out


def _preference(log_preference: LogPreference, predicted: Mapping[str, Tensor], n: int) -> Tensor:
    out = log_preference(predicted)
    if not isinstance(out, Tensor) or out.shape != (n,):
        got = tuple(out.shape) if isinstance(out, Tensor) else describe(out)
        raise ValueError(f"log_preference returned {got}, expected a tensor of shape ({n},)")
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
            any actions that are held fixed (within their bounds); None if the graph has
            no other roots.
        targets: name -> ``(N, dim)`` desired values of non-action variables; with the
            default Gaussian preference the loss is ``sum 0.5 ((Phi - target) / scale)^2``.
        actions: action variables to optimise (default: every action not in ``state``).
        log_preference: optional callable ``predicted -> (N,)`` log-preference replacing
            the Gaussian one (then ``targets`` may be None).
        scale: Gaussian preference scale > 0 (targets' units), scalar or one per target.
        steps: Adam iterations K_act (thesis B2: 200).
        lr: Adam learning rate eta_act (thesis B2: 0.05).
        init: ``"midpoint"`` (thesis B2), ``"random"`` or name -> ``(N, dim)`` within bounds.
        noise: name -> ``(N, dim)`` standardised residuals u (e.g. abducted) of variables
            that are neither given nor optimised; default: expected residuals u-bar (Alg. 4.2).
        seed: seed for ``init="random"`` (local generator).
        progress_bar: show a tqdm bar.

    Returns:
        :class:`ActionResult`. After each Adam step the actions are clipped to their
        bounds, so ``actions`` always lies within them.

    Raises:
        ValueError: bad state, targets, init or noise values (see
            :func:`models.world.as_values`), fixed actions outside their bounds, unknown or
            non-action ``actions``, a bad scale, log-preference or optimiser argument.
        FloatingPointError: the final loss is NaN or inf.
    """
    model = require_world_model(model)
    graph = model.graph
    steps = check_int("steps", steps, minimum=1)
    lr = check_float("lr", lr, minimum=0.0, min_open=True)
    seed = check_seed("seed", seed)
    progress_bar = check_bool("progress_bar", progress_bar)
    if log_preference is not None:
        check_callable("log_preference", log_preference)
    given, n = as_values(graph, state, what="state", dtype=model.dtype)
    tgt, n = as_values(graph, targets, n=n, what="targets", dtype=model.dtype)
    if n is None:
        raise ValueError("state and targets are empty; cannot tell the number of units")
    check_action_bounds(graph, given, "state")
    if actions is None:
        actions = [a for a in graph.actions if a not in given]
    actions = check_names("actions", actions)
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
    eps, _ = as_values(graph, noise, n=n, what="noise", dtype=model.dtype)
    clash = sorted(k for k in eps if k in given or k in actions)
    if clash:
        raise ValueError(
            f"noise names {clash}, which are given in state or optimised; residuals are for the other variables"
        )

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
            per_unit = -_preference(log_preference, forward(), n)
            loss = per_unit.sum()
            loss.backward()
            optim.step()
            with torch.no_grad():
                for k, p in params.items():
                    p.copy_(torch.clamp(p, *bounds[k]))
            history.append(float(loss.detach()) / n)
        with torch.no_grad():
            predicted = forward()
            final = -_preference(log_preference, predicted, n)
    if not torch.isfinite(final).all():
        raise FloatingPointError("action inference produced a non-finite loss; check targets and scales")
    acts = {k: v.detach().clone() for k, v in params.items()}
    return ActionResult(acts, {k: v.detach() for k, v in predicted.items()}, tuple(history), final.detach())
