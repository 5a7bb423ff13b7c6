"""Plan: a pure function of the model, the belief and the targets (Alg. 4.2 over a horizon, MPC).

:func:`plan` runs :func:`inference.infer_action` with the sampling planner (CEM / iCEM, then
projected Adam) over ``H`` steps through :meth:`models.WorldModel.rollout`, for one unit whose
state is the belief (the lag-1 roots: ``q_prev``, ``ee_prev``, ``pos_prev.o`` ...). The
preference over the predicted trajectory is, per scored step,

    log p = - sum_o [ w_g c(pos.o - target_o) + w_e c(ee - pos.o) + w_b c(ee - behind_o) ]
            - w_a |act|^2 - w_m |act - q_prev|^2

with ``c(x) = 0.5 |x|^2 / scale^2`` (Gaussian), ``|x|_2 / scale`` (distance) or ``|x|_1 / scale``
(L1, PETS's Pusher cost: ``w_g = 1.25, w_e = 0.5, w_a = 0.1``), the effector terms on its first
d components, and the move term for position servos (actions in joint units). The optional
shaping term (``w_b = behind_weight``, 0 by default) pulls the effector to the point behind the
object on the far side from the goal, in the table plane (x-y),

    behind_o = pos.o - r (target_o - pos.o) / |target_o - pos.o|,    r = ``behind_offset``,

where a push along the object-goal line starts. The agent executes the first action and plans
again at the next step (model-predictive control), warm-started from the rest of the sequence
shifted by one step (:func:`inference.planning.shift_plan`). With ``risk="mean"`` the cost is
the expectation over the ensemble members' particles (each member on its own trajectory, as
PETS propagates particles), with ``("quantile", q)`` their q-quantile; with ``"disagreement"``
their spread on the target sites is weighed.

The returned :class:`Plan` also carries the model's one-step prediction of every targeted
object's displacement under the first action, with its predictive sd (aleatoric and epistemic)
and each member's value: the intervals that the experiments hold against what happens.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import torch
from torch import Tensor

from inference import ReplayNoise, infer_action
from models import WorldModel
from pal.agent.config import PlanConfig
from pal.agent.graph_frame import displacement_site, world_displacement
from pal.checks import check_int

__all__ = [
    "Plan",
    "PlanRequest",
    "behind",
    "distance",
    "expected_distance",
    "one_step",
    "plan",
    "plan_batch",
    "preference",
    "site",
]


@dataclass(frozen=True)
class Plan:
    """A planned action sequence and what the model expects of it.

    Attributes:
        action: (A,) the first action.
        sequence: (H, A) the whole planned sequence.
        targets: object -> (d,) target, m.
        predicted: object -> (d,) position at the horizon's end (the members' mean), m.
        objective: predicted distance to the targets at the horizon's end, summed over objects, m.
        step_mean, step_sd: object -> (d,) predicted displacement over the first step and its
            predictive sd (aleatoric and epistemic), m.
        mode: why it was chosen (``"goal"``, ``"curious"`` ...).
        loss: the planner's loss of the sequence, ``-log p`` with the risk (None: not given).
    """

    action: np.ndarray
    sequence: np.ndarray
    targets: dict[str, np.ndarray]
    predicted: dict[str, np.ndarray]
    objective: float
    step_mean: dict[str, np.ndarray]
    step_sd: dict[str, np.ndarray]
    mode: str = "goal"
    loss: float | None = None


def distance(x: Tensor, kind: str, scale: float) -> Tensor:
    """``c(x)`` of the module docstring over the last axis: ``(..., d) -> (...)``.

    ``kind`` is ``"gaussian"`` (``0.5 |x|^2 / scale^2``), ``"distance"`` (``|x|_2 / scale``) or
    ``"l1"`` (``|x|_1 / scale``).
    """
    if kind == "gaussian":
        return 0.5 * (x / scale).pow(2).sum(-1)
    if kind == "l1":
        return x.abs().sum(-1) / scale
    return torch.sqrt(x.pow(2).sum(-1) + 1e-12) / scale


def behind(pos: Tensor, target: Tensor, offset: float) -> Tensor:
    """The point ``offset`` m behind ``pos`` on the far side from ``target`` in x-y: ``(..., 2)``."""
    away = pos[..., :2] - target[..., :2]
    return pos[..., :2] + offset * away / torch.sqrt(away.pow(2).sum(-1, keepdim=True) + 1e-12)


def site(name: str, effector: str | None) -> str:
    """The site a target of ``name`` is scored on: ``ee`` for the effector, else ``pos.<name>``."""
    return "ee" if name == effector else f"pos.{name}"


def preference(
    targets: Mapping[str, Tensor], config: PlanConfig, effector: bool, reach: str | None = None
) -> Callable[[Mapping[str, Tensor]], Tensor]:
    """The log-preference of the module docstring: ``values (..., N, dim) -> (..., N)``.

    A target named ``reach`` (the effector's name) is scored on the effector's first d components:
    ``w_g c(ee[:d] - target)``.
    """
    scale, kind = config.action.scale, config.preference

    def log_p(values: Mapping[str, Tensor]) -> Tensor:
        total: Tensor | float = 0.0
        for o, t in targets.items():
            if o == reach:
                total = total + config.goal_weight * distance(
                    values["ee"][..., : t.shape[-1]] - t, kind, scale
                )
                continue
            pos = values[f"pos.{o}"]
            total = total + config.goal_weight * distance(pos - t, kind, scale)
            if effector and config.effector_weight:
                total = total + config.effector_weight * distance(
                    values["ee"][..., : pos.shape[-1]] - pos, kind, scale
                )
            if effector and config.behind_weight:
                shaped = values["ee"][..., :2] - behind(pos, t, config.behind_offset)
                total = total + config.behind_weight * distance(shaped, kind, scale)
        if config.action_weight:
            total = total + config.action_weight * values["act"].pow(2).sum(-1)
        if config.move_weight:
            total = total + config.move_weight * (values["act"] - values["q_prev"]).pow(2).sum(-1)
        return -total

    return log_p


def one_step(
    model: WorldModel,
    belief: Mapping[str, np.ndarray],
    action: np.ndarray,
    objects: tuple[str, ...],
    effector: str | None = None,
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], dict[str, np.ndarray]]:
    """The model's prediction of each object's displacement under ``action`` from ``belief``.

    An entry named ``effector`` gets the effector's displacement ``dee``.

    Returns:
        ``(mean, sd, members)``: object -> (d,) mean and predictive sd (total, m), and
        (K, d) each member's mean.
    """
    dtype = model.dtype
    values = {k: torch.as_tensor(np.asarray(v)[None], dtype=dtype) for k, v in belief.items()}
    values["act"] = torch.as_tensor(np.asarray(action)[None], dtype=dtype)
    mean = model.predict(values)
    sd = model.predict_scale(values)
    members = model.predict(values, members=True)
    d = {o: "dee" if o == effector else displacement_site(model.graph, o) for o in objects}
    step = {
        o: (mean["dee"], sd["dee"]) if o == effector else world_displacement(model.graph, mean, sd, o)
        for o in objects
    }
    m = {o: step[o][0][0].numpy().astype(np.float64) for o in objects}
    s = {o: step[o][1][0].numpy().astype(np.float64) for o in objects}
    k = {o: members[d[o]][:, 0].numpy().astype(np.float64) for o in objects}
    return m, s, k


def expected_distance(
    model: WorldModel,
    belief: Mapping[str, np.ndarray],
    sequence: np.ndarray,
    targets: Mapping[str, np.ndarray],
    *,
    draws: int = 16,
    seed: int = 0,
    effector: str | None = None,
) -> float:
    """The model's expected distance to the targets at the end of ``sequence``, m.

    ``E ||x_H - t||`` summed over targets, the expectation over the model's predictive
    distribution: ``draws`` rollouts of ``sequence`` (H, A) from ``belief`` with sampled residuals
    (and sampled switches), each on every ensemble member's own trajectory (TS), K x draws paths.
    A plan's ``objective`` is ``||E x_H - t||`` of the members' mean without noise, which is never
    larger (Jensen) and, chosen by the planner, optimistic; this is the model's prediction of the
    distance that will be realized.
    """
    draws = check_int("draws", draws)
    seq = np.asarray(sequence, dtype=np.float64)
    if seq.ndim != 2:
        raise ValueError(f"sequence must be (H, A), got shape {seq.shape}")
    dtype = model.dtype
    initial = {
        k: torch.as_tensor(np.repeat(np.asarray(v, np.float64)[None], draws, 0), dtype=dtype)
        for k, v in belief.items()
    }
    acts = torch.as_tensor(np.repeat(seq[None], draws, 0), dtype=dtype)
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        out = model.rollout(initial, {"act": acts}, noise="sampled", generator=gen, members=True)
    total = 0.0
    for o, t in targets.items():
        goal = torch.as_tensor(np.asarray(t, np.float64), dtype=dtype)
        final = out[site(o, effector)][..., -1, : goal.shape[-1]]
        total += float(torch.linalg.norm(final - goal, dim=-1).mean())
    return total


def plan(
    model: WorldModel,
    belief: Mapping[str, np.ndarray],
    targets: Mapping[str, np.ndarray],
    config: PlanConfig,
    *,
    seed: int,
    init: np.ndarray | None = None,
    mode: str = "goal",
    effector: str | None = None,
    noise: Mapping[str, np.ndarray] | None = None,
) -> Plan:
    """Plan towards ``targets`` from ``belief`` (module docstring).

    Args:
        model: the world model (fixed).
        belief: the lag-1 roots of the graph: name -> (dim,) current state estimate.
        targets: object -> (d,) target position, m.
        config: horizon, sampling, preference and risk.
        seed: seeds the sampling stage.
        init: optional (H, A) start of the search (a warm start), within the action bounds.
        mode: recorded in the plan.
        effector: the effector's name: a target of that name is for ``ee`` (its first d components).
        noise: site -> (dim,) residual replayed on every rollout step (:mod:`pal.agent.correction`).

    Raises:
        ValueError: a target or belief entry that is missing or of the wrong shape (see
            :func:`inference.infer_action`).
    """
    request = PlanRequest(belief, targets, seed, init, mode, noise)
    return plan_batch(model, [request], config, effector=effector)[0]


@dataclass(frozen=True)
class PlanRequest:
    """One unit's planning problem: the arguments of :func:`plan` that differ between units."""

    belief: Mapping[str, np.ndarray]
    targets: Mapping[str, np.ndarray]
    seed: int
    init: np.ndarray | None = None
    mode: str = "goal"
    noise: Mapping[str, np.ndarray] | None = None


def plan_batch(
    model: WorldModel, requests: Sequence[PlanRequest], config: PlanConfig, *, effector: str | None = None
) -> list[Plan]:
    """Plan for N units in one search: unit i's plan is :func:`plan`'s for ``requests[i]``.

    The units' candidates (R, N, H, A) go through each rollout step together, so the step's
    Python cost is paid once for all N (the MPC steps of agents run in lockstep). Each unit keeps
    its own elites; the units' samples come from one generator seeded by the first request's
    seed, so with N > 1 a unit's plan differs from the one it gets alone by its random draws.

    Raises:
        ValueError: no requests; requests with different belief or target names; residuals
            (``noise``, per unit) with N > 1; or as :func:`plan`.
    """
    if not requests:
        raise ValueError("plan_batch needs at least one request, got none")
    first = requests[0]
    for k, r in enumerate(requests):
        if set(r.belief) != set(first.belief) or set(r.targets) != set(first.targets):
            raise ValueError(
                f"request {k} has belief {sorted(r.belief)} and targets {sorted(r.targets)}, expected the "
                f"names of request 0: {sorted(first.belief)} and {sorted(first.targets)}"
            )
    if len(requests) > 1 and any(r.noise for r in requests):
        raise ValueError(
            f"residuals (noise) are replayed for one unit only; got them with {len(requests)} requests"
        )
    dtype = model.dtype
    state = {k: _stacked([r.belief[k] for r in requests], dtype) for k in first.belief}
    tgt = {o: _stacked([r.targets[o] for r in requests], dtype) for o in first.targets}
    options = config.action
    disagreement = isinstance(options.risk, tuple) and options.risk[0] == "disagreement"
    program = model
    if (
        first.noise
    ):  # the correction: residuals replayed on every rollout step (the torch twin of ReplayNoise)
        eps = {k: _stacked([v], dtype) for k, v in first.noise.items()}
        program = ReplayNoise(eps, default="expected")(model)
    result = infer_action(
        program,
        state,
        {site(o, effector): t for o, t in tgt.items()} if disagreement else None,
        num_steps=max(options.sampling.refine_steps, 1),
        options=replace(
            options,
            log_preference=preference(tgt, config, "ee" in model.graph, effector),
            init=_start(model, [r.init for r in requests], options.horizon),
        ),
        seed=first.seed,
    )
    return [_unit_plan(model, result, i, r, config, effector) for i, r in enumerate(requests)]


def _stacked(values: Sequence[np.ndarray], dtype: torch.dtype) -> Tensor:
    """Per-unit ``(dim,)`` values as one ``(N, dim)`` tensor of the model's dtype."""
    return torch.as_tensor(np.stack([np.asarray(v, dtype=np.float64) for v in values]), dtype=dtype)


def _start(model: WorldModel, inits: Sequence[np.ndarray | None], horizon: int) -> str | dict[str, Tensor]:
    """The search's start: the box midpoint, or the units' ``(H, A)`` warm starts (the midpoint where None)."""
    if all(i is None for i in inits):
        return "midpoint"
    low, high = model.bounds("act")
    mid = ((low + high) / 2).expand(horizon, low.shape[0])
    rows = torch.stack(
        [
            mid if i is None else torch.as_tensor(np.asarray(i, dtype=np.float64), dtype=model.dtype)
            for i in inits
        ]
    )
    return {"act": rows if horizon > 1 else rows[:, 0]}


def _unit_plan(
    model: WorldModel, result: Any, i: int, request: PlanRequest, config: PlanConfig, effector
) -> Plan:
    """Unit i's :class:`Plan` from the batched search's ``result``."""
    h = config.action.horizon
    acts = result.actions["act"][i].numpy().astype(np.float64).reshape(h, -1)
    targets = {o: np.asarray(t, dtype=np.float64) for o, t in request.targets.items()}
    predicted = {}
    for o, t in targets.items():
        path = result.predicted[site(o, effector)][i]
        predicted[o] = path.reshape(-1, path.shape[-1])[-1].numpy()[: t.shape[-1]].astype(np.float64)
    objective = float(sum(np.linalg.norm(predicted[o] - targets[o]) for o in targets))
    mean, sd, _ = one_step(model, request.belief, acts[0], tuple(targets), effector)
    return Plan(
        acts[0].copy(),
        acts,
        targets,
        predicted,
        objective,
        mean,
        sd,
        request.mode,
        float(result.final_loss[i]),
    )
