"""Curiosity that seeks contact: an action-specific contact gate on the on branch's disagreement, with novelty.

For a candidate action sequence a_0 .. a_{H-1} from the belief s_0, the model is rolled forward
on the members' mean state (Alg. 4.1; each step evaluates every member, ``members=True``, with
expected residuals, in which a gated ``dpos.o`` takes its mixture mean over the contact switch).
At step t the score of object o is

    g_o(s_t, a_t) = pi_o(s_t, a_t) * D_o(s_t, a_t)                          (the contact gate)

- ``pi_o = mean_k P_k(contact.o = 1 | rel_prev.o, rel.o)``: the model's probability that *this
  action* switches contact on, the gated site's switch at the hand's predicted position
  relative to the object after the step (:mod:`pal.agent.graph`);
- ``D_o = sum_d Var_k[f_1^(k)(pa | contact.o = 1)_d] / scale^2``: the epistemic disagreement of
  the members' on branches (the displacement they predict *if* the object is touched), in
  units of the preference scale ``scale`` (m).

An action that keeps the hand away from the objects scores ~0 however much the on branches
disagree, and an action that touches an object whose pushes the members agree on scores ~0
too. The sequence's score sums the gates over the horizon, each times a count-based novelty
of the object's predicted position, and subtracts a joint-limit penalty:

    score(a) = sum_t sum_o g_o(s_t, a_t) * nu_o(pos_t,o) - w * sum_t sum_j l(a_t,j),
    nu_o(x) = 1 / sqrt(1 + n_o(cell(x))),
    l(a) = max(0, 1 - dist(a, bound) / (m * range))^2,

with ``n_o`` the number of steps in which the agent's estimate of o moved more than
``moved`` m and ended in that cell of the :class:`pal.agent.curiosity.GridCuriosity` grid (the
counts of the density method, here of pushed positions), and ``m`` the limit margin (a share of
each action's range). The search (:func:`inference.planning.cross_entropy_search`) starts at
"hold" (the servo targets equal to the joint angles) with a spread of ``sampling.init_std`` of
the action range, over a horizon of H >= 5 steps so that the hand can first travel to an object.

The causal action influence of :mod:`pal.agent.influence` (CAI, over actions drawn from the
whole box) is kept as a diagnostic beside the gate (:func:`diagnose`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from inference.planning import cross_entropy_search
from models import WorldModel
from pal.agent.config import CuriosityConfig
from pal.agent.curiosity import GridCuriosity
from pal.agent.influence import influence

__all__ = [
    "ContactSearch",
    "StepGate",
    "at_limit",
    "contact_search",
    "diagnose",
    "novelty",
    "push_counts",
    "step_gate",
]


@dataclass(frozen=True)
class StepGate:
    """One expected step of every member from a batch of states.

    Attributes:
        next_state: lag-1 root -> ``(R, dim)`` the state after the step (mean over members).
        p_on: object -> ``(R,)`` mean over members of P(contact.o = 1).
        spread: object -> ``(R,)`` on-branch disagreement D_o (module docstring), scale units.
        position: object -> ``(R, d)`` mean over members of the predicted position, m.
    """

    next_state: dict[str, Tensor]
    p_on: dict[str, Tensor]
    spread: dict[str, Tensor]
    position: dict[str, Tensor]

    def gate(self, o: str) -> Tensor:
        """``(R,)`` the contact gate ``pi_o * D_o``."""
        return self.p_on[o] * self.spread[o]


def _check_gated(model: WorldModel, objects: Sequence[str]) -> None:
    missing = [o for o in objects if f"contact.{o}" not in model.discrete]
    if missing:
        raise ValueError(
            f"the contact gate needs a Bernoulli contact.o switch for objects {missing}; build the model with "
            "ModelConfig(displacement='gated')"
        )


def step_gate(
    model: WorldModel, state: Mapping[str, Tensor], act: Tensor, objects: Sequence[str], scale: float
) -> StepGate:
    """The contact gate of one step (module docstring).

    Args:
        model: a world model with a gated ``dpos.o`` and a ``contact.o`` switch per object.
        state: lag-1 root -> ``(R, dim)``, shared by the members.
        act: ``(R, A)`` actions within the model's bounds.
        objects: the objects to score.
        scale: the disagreement's unit, m (> 0).

    Returns:
        :class:`StepGate`.
    """
    if act.ndim != 2:
        raise ValueError(f"act has shape {tuple(act.shape)}, expected (R, A)")
    values = {**state, "act": act}
    r = act.shape[0]
    on = {f"contact.{o}": torch.ones(r, 1, dtype=act.dtype) for o in objects}
    forced = model.predict({**values, **on}, members=True)  # the on branches: dpos.o given contact
    mixed = model.predict(values, members=True)  # the expected step: the mixture over the switch
    p_on, spread, position = {}, {}, {}
    for o in objects:
        given = {
            p: forced[p] for p in model.graph.parents(f"contact.{o}")
        }  # rel_prev, rel (push frame: local)
        p_on[o] = model.probs(f"contact.{o}", given)[..., 1].mean(0)
        spread[o] = forced[f"dpos.{o}"].var(0, unbiased=False).sum(-1) / scale**2
        position[o] = mixed[f"pos.{o}"].mean(0)
    nxt = {root: mixed[src].mean(0) for root, src in model.graph.lagged.items() if model.graph.is_root(root)}
    return StepGate(nxt, p_on, spread, position)


def push_counts(est_prev: np.ndarray, est: np.ndarray, grid: GridCuriosity, moved: float) -> GridCuriosity:
    """``grid`` with the estimated positions of one object after every step in which it moved > ``moved`` m.

    Args:
        est_prev: ``(N, d >= 2)`` the estimate before each step (NaN rows: unknown, skipped), m.
        est: ``(N, d >= 2)`` the estimate after it, m.
        grid: the counts to add to.
        moved: displacement that counts as a push, m.
    """
    d = np.linalg.norm(est - est_prev, axis=1)
    keep = np.isfinite(d) & (d > moved)
    if keep.any():
        grid.partial_fit(est[keep][:, :2])
    return grid


def novelty(grid: GridCuriosity, points: Tensor) -> Tensor:
    """``nu(x) = 1 / sqrt(1 + n(cell(x)))`` for ``(R, d >= 2)`` positions, m (the table plane x, y): ``(R,)`` in (0, 1]."""
    n = grid.counts_at(points[..., :2].detach().numpy())
    return torch.as_tensor(1.0 / np.sqrt(1.0 + n), dtype=points.dtype)


def limit_penalty(a: Tensor, low: Tensor, high: Tensor, margin: float) -> Tensor:
    """``sum_t sum_j max(0, 1 - dist(a, bound) / (margin * range))^2`` of ``(R, H, A)`` sequences: ``(R,)``."""
    dist = torch.minimum(a - low, high - a) / (margin * (high - low))
    return (1.0 - dist).clamp_min(0.0).pow(2).sum((-1, -2))


def at_limit(actions: np.ndarray, low: np.ndarray, high: np.ndarray, share: float = 0.01) -> np.ndarray:
    """``(N,)`` bool: some action of the row lies within ``share`` of its range of a bound."""
    a = np.asarray(actions, dtype=np.float64)
    tol = share * (np.asarray(high) - np.asarray(low))
    return ((a - low <= tol) | (high - a <= tol)).any(-1)


@dataclass(frozen=True)
class ContactSearch:
    """The searched sequence and its score.

    Attributes:
        sequence: ``(H, A)`` the best sequence.
        information: its summed novelty-weighted gates (the score without the limit penalty).
        score: the score (information minus the limit penalty).
    """

    sequence: np.ndarray
    information: float
    score: float


def contact_search(
    model: WorldModel,
    belief: Mapping[str, np.ndarray],
    hold: np.ndarray,
    objects: tuple[str, ...],
    grids: Mapping[str, GridCuriosity],
    config: CuriosityConfig,
    scale: float,
    generator: torch.Generator,
) -> ContactSearch:
    """The action sequence of highest score from ``belief`` (module docstring).

    Args:
        model: the gated world model (an ensemble; with K = 1 every gate is 0).
        belief: lag-1 root -> ``(dim,)`` the current state.
        hold: ``(A,)`` the action that holds still (the search's start).
        objects: the objects to explore.
        grids: object -> the counts of its pushed positions (:func:`push_counts`).
        config: horizon, search, penalty.
        scale: the disagreement's unit, m.
        generator: the search's only source of randomness.
    """
    _check_gated(model, objects)
    dtype, h = model.dtype, config.horizon
    low, high = model.bounds("act")
    start = torch.as_tensor(np.asarray(hold, dtype=np.float64), dtype=dtype)
    if start.shape != low.shape:
        raise ValueError(f"hold has shape {tuple(start.shape)}, expected {tuple(low.shape)}")
    start = torch.clamp(start, low, high).expand(1, h, low.shape[0]).clone()
    init = {k: torch.as_tensor(np.asarray(v, dtype=np.float64)[None], dtype=dtype) for k, v in belief.items()}

    def terms(a: Tensor) -> tuple[Tensor, Tensor]:  # (R, H, A) -> information (R,), penalty (R,)
        r = a.shape[0]
        state = {k: v.expand(r, v.shape[-1]) for k, v in init.items()}
        info = torch.zeros(r, dtype=dtype)
        for t in range(h):
            g = step_gate(model, state, a[:, t], objects, scale)
            for o in objects:
                info = info + g.gate(o) * novelty(grids[o], g.position[o])
            state = g.next_state
        return info, config.limit_weight * limit_penalty(a, low, high, config.limit_margin)

    def objective(a: Tensor) -> Tensor:  # (R, 1, H, A) -> (R, 1) loss = -score
        info, penalty = terms(a[:, 0])
        return (penalty - info)[:, None]

    with torch.no_grad():
        found = cross_entropy_search(objective, start, low, high, config.sampling, generator)
        best = found.elites[0, 0]
        info, penalty = terms(best[None])
    return ContactSearch(best.numpy().astype(np.float64), float(info[0]), float(info[0] - penalty[0]))


def diagnose(
    model: WorldModel,
    belief: Mapping[str, np.ndarray],
    action: np.ndarray,
    objects: tuple[str, ...],
    config: CuriosityConfig,
    scale: float,
    generator: torch.Generator,
) -> dict[str, dict[str, float]]:
    """The gate, the contact probability and CAI of one executed action, per object.

    Returns:
        ``{"gate": {o: pi_o D_o}, "p_on": {o: pi_o}, "influence": {o: I_o(s), nats}}`` at the
        belief (CAI from :func:`pal.agent.influence.influence` with ``config.influence_samples``).
    """
    _check_gated(model, objects)
    dtype = model.dtype
    state = {
        k: torch.as_tensor(np.asarray(v, dtype=np.float64)[None], dtype=dtype) for k, v in belief.items()
    }
    act = torch.as_tensor(np.asarray(action, dtype=np.float64)[None], dtype=dtype)
    with torch.no_grad():
        g = step_gate(model, state, act, objects, scale)
        cai = influence(model, state, objects, config.influence_samples, generator)
    return {
        "gate": {o: float(g.gate(o)[0]) for o in objects},
        "p_on": {o: float(g.p_on[o][0]) for o in objects},
        "influence": {o: float(cai[o][0]) for o in objects},
    }
