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

from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace

import numpy as np
import torch
from torch import Tensor

from inference import ReplayNoise, infer_action
from models import WorldModel
from pal.agent.config import PlanConfig
from pal.agent.graph_frame import displacement_site, world_displacement
from pal.checks import check_int

__all__ = ["Plan", "behind", "distance", "expected_distance", "one_step", "plan", "preference", "site"]


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
    dtype = model.dtype
    state = {
        k: torch.as_tensor(np.asarray(v, dtype=np.float64)[None], dtype=dtype) for k, v in belief.items()
    }
    tgt = {o: torch.as_tensor(np.asarray(t, dtype=np.float64)[None], dtype=dtype) for o, t in targets.items()}
    options = config.action
    h = options.horizon
    disagreement = isinstance(options.risk, tuple) and options.risk[0] == "disagreement"
    start: object = "midpoint"
    if init is not None:
        a = torch.as_tensor(np.asarray(init, dtype=np.float64), dtype=dtype)
        start = {"act": a[None] if h > 1 else a[:1]}
    program = model
    if noise:  # the correction: residuals replayed on every rollout step (the torch twin of ReplayNoise)
        eps = {k: torch.as_tensor(np.asarray(v, np.float64)[None], dtype=dtype) for k, v in noise.items()}
        program = ReplayNoise(eps, default="expected")(model)
    result = infer_action(
        program,
        state,
        {site(o, effector): t for o, t in tgt.items()} if disagreement else None,
        num_steps=max(options.sampling.refine_steps, 1),
        options=replace(
            options, log_preference=preference(tgt, config, "ee" in model.graph, effector), init=start
        ),
        seed=seed,
    )
    acts = result.actions["act"][0].numpy().astype(np.float64).reshape(h, -1)
    final = {
        o: result.predicted[site(o, effector)][0]
        .reshape(-1, result.predicted[site(o, effector)].shape[-1])[-1]
        .numpy()[: tgt[o].shape[-1]]
        for o in tgt
    }
    predicted = {o: v.astype(np.float64) for o, v in final.items()}
    objective = float(
        sum(np.linalg.norm(predicted[o] - np.asarray(targets[o], dtype=np.float64)) for o in tgt)
    )
    mean, sd, _ = one_step(model, belief, acts[0], tuple(tgt), effector)
    return Plan(
        acts[0].copy(),
        acts,
        {o: np.asarray(t, np.float64) for o, t in targets.items()},
        predicted,
        objective,
        mean,
        sd,
        mode,
        float(result.final_loss[0]),
    )
