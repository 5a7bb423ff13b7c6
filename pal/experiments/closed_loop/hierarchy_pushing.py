"""The three-layer hierarchy of the pushing world (thesis §6.4.1, Eq. 6.2-6.3).

- **Body** (LSML): the arm sites of the agent's fitted world model (``act, q_prev -> dq``,
  ``q_prev, dq -> dee``, ``ee_prev, dee -> ee``; copies of the fitted mechanisms). The hierarchy
  plans one step at a time, so the lagged roots ``q_prev``, ``ee_prev`` are the current state and
  are not linked to their successors (``lag_of`` is dropped).
- **Event** (IBEL): per object o, ``push.o`` (2,), m: the hand's displacement in the table plane
  over a step in which it touched o for at least ``contact_threshold`` of the step (else 0),
  an abstraction over a window of 2 samples of the hand and touch series; its direction is the
  push direction, its length the push extent. ``onset.o``: contact onset.
- **Object** (HOEL): per object, ``push.o`` (the action root, bounds ``±max_push`` m per
  component) ``-> dpos.o = A_o push.o``, ``pos.o = pos_prev.o + dpos.o``. The 2 x 2 gain
  ``A_o`` is a ridge fit on the babbling history's abstractions (bottom-up evidence of the
  hierarchy: event ``push.o`` against object ``dpos.o``, aligned at the window start), shrunk
  towards the identity ("the box follows the hand") with weight ``ridge`` m²:

      A = (Y^T X + ridge I)(X^T X + ridge I)^-1,   rows: steps with a push event.

**Realise** (top-down, the push event's inverse): with p the object's position, u the push
direction and D = R + r + gap the approach distance (R the object's circumscribed radius, r the
hand's), three hand waypoints (``ee`` targets, at the hand's current height):

0. ``via``: D from p, 45 deg between the hand's side and the back of the object (a way round it);
1. ``approach``: p - D u, behind the object on the push line;
2. ``through``: p - (e + r) u + |push| u, with e the object's smallest half extent: the hand
   pushes the object along u by at most the push extent.

:func:`push_phase` picks the current one from the hand's place relative to the object.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import torch
from torch import Tensor

from inference import ActionOptions, SamplingConfig
from inference.hierarchy import Hierarchy, Layer, LevelQuery
from models import CausalGraph, LinearMechanism, Variable, WorldModel
from models.abstraction import Abstraction, ContactOnset, Displacement
from pal.agent.history import History
from pal.baselines.scripted_pusher import HAND_RADIUS
from pal.checks import check_float, check_int
from pal.sim.pushing import BOX_HALF, OBJECT_RADIUS

__all__ = [
    "PHASES",
    "HierarchyConfig",
    "PushEvent",
    "body_layer",
    "episode_series",
    "fit_push_gains",
    "make_realise",
    "push_phase",
    "pushing_hierarchy",
]

#: The realised phases of a push, in order.
PHASES = ("via", "approach", "through")
#: Smallest half extent of each object's footprint, m (where the hand meets it head on).
_NEAR_FACE = {"box": float(min(BOX_HALF[:2])), "ball": OBJECT_RADIUS["ball"]}


@dataclass(frozen=True)
class HierarchyConfig:
    """Settings of the pushing hierarchy (module docstring); lengths in metres.

    Attributes:
        max_push: bound of each component of a push event (one decision's push), m.
        gap: clearance between the hand and the object's circumscribed circle at the approach, m.
        align: largest sideways offset of the hand from the push line for the ``through`` phase, m.
        contact_threshold: share of a step in contact that makes a push event, in (0, 1].
        ridge: weight of the identity prior of the push gains, m².
        object_query: the object level's action inference (Adam steps; options: preference
            scale of the push events, m, and Adam's rate), passed to :class:`inference.hierarchy.Hierarchy`.
        body_query: the body level's: its sampling stage (CEM) and Adam refinement
            (``options.sampling.refine_steps`` Adam steps; ``num_steps`` counts only without it) and
            ``options.scale``, the preference scale of the hand waypoints, m.
        context_samples: draws of each layer for contextualisation.
        threshold: smallest standardised relevance of an active edge (Eq. 6.6).
    """

    max_push: float = 0.03
    gap: float = 0.01
    align: float = 0.015
    contact_threshold: float = 0.5
    ridge: float = 1e-3
    object_query: LevelQuery = LevelQuery(60, ActionOptions(scale=0.005, lr=0.005))
    body_query: LevelQuery = LevelQuery(
        10,
        ActionOptions(
            scale=0.01, sampling=SamplingConfig(population=16, elites=4, iterations=2, refine_steps=10)
        ),
    )
    context_samples: int = 128
    threshold: float = 0.01

    def __post_init__(self) -> None:
        check_float("max_push", self.max_push, 0.0, open_low=True)
        check_float("gap", self.gap, 0.0)
        check_float("align", self.align, 0.0, open_low=True)
        check_float("contact_threshold", self.contact_threshold, 0.0, 1.0, open_low=True)
        check_float("ridge", self.ridge, 0.0, open_low=True)
        for name in ("object_query", "body_query"):
            query = getattr(self, name)
            if not isinstance(query, LevelQuery):
                raise ValueError(f"{name} must be a LevelQuery, got {type(query).__name__}")
            check_float(f"{name}.options.scale", query.options.scale, 0.0, open_low=True)
        sampling = self.body_query.options.sampling
        if sampling is None or sampling.refine_steps is None:
            raise ValueError(
                "body_query.options.sampling must be a SamplingConfig with refine_steps set: the body level "
                "plans with CEM, then that many Adam steps"
            )
        check_int("context_samples", self.context_samples, 2)
        check_float("threshold", self.threshold, 0.0)


@dataclass(frozen=True)
class PushEvent:
    """h of ``push.o``: the effector's planar displacement over the window where ``gate`` reached ``threshold``, else 0."""

    effector: str
    gate: str
    threshold: float

    def __call__(self, wins: Mapping[str, Tensor]) -> Tensor:
        """``{effector: (B, W, E), gate: (B, W, 1)} -> (B, 2)``."""
        ee, touch = wins[self.effector], wins[self.gate]
        moved = ee[:, -1, :2] - ee[:, 0, :2]
        hit = (touch[:, 1:].amax(dim=(1, 2)) >= self.threshold).to(moved.dtype)[:, None]
        return moved * hit


def body_layer(model: WorldModel) -> Layer:
    """The arm sites of the agent's world model (module docstring)."""
    g = model.graph
    names = [n for n in g.names if "." not in n]
    variables = [replace(g[n], lag_of=None) if g[n].lag else g[n] for n in names]
    edges = [(p, c) for p, c in g.edges if p in names and c in names]
    return Layer("body", model.with_graph(CausalGraph(variables, edges)))


def _event_layer(objects: Sequence[str], threshold: float) -> Layer:
    variables, abstractions = [], []
    for o in objects:
        push = Variable(f"push.{o}", "observed", 2, unit="m", description="push extent and direction")
        onset = Variable(f"onset.{o}", "observed", 1, unit="1", description="contact onset")
        variables += [push, onset]
        abstractions += [
            Abstraction(push.name, ("ee", f"touch.{o}"), 2, PushEvent("ee", f"touch.{o}", threshold), push),
            Abstraction(onset.name, (f"touch.{o}",), 2, ContactOnset(f"touch.{o}", threshold), onset),
        ]
    return Layer("event", WorldModel(CausalGraph(variables)), tuple(abstractions))


def _object_layer(
    objects: Sequence[str], gains: Mapping[str, np.ndarray], sigma: Mapping[str, float], max_push: float
) -> Layer:
    variables, edges, mechs, abstractions = [], [], {}, []
    for o in objects:
        dpos = Variable(f"dpos.{o}", "latent", 2, unit="m", description="displacement over the push")
        variables += [
            Variable(f"push.{o}", "action", 2, bounds=(-max_push, max_push), unit="m"),
            Variable(f"pos_prev.{o}", "observed", 2, unit="m", lag=1, lag_of=f"pos.{o}"),
            dpos,
            Variable(f"pos.{o}", "latent", 2, unit="m"),
        ]
        edges += [(f"push.{o}", dpos.name), (f"pos_prev.{o}", f"pos.{o}"), (dpos.name, f"pos.{o}")]
        mechs[dpos.name] = LinearMechanism.from_coefficients(gains[o], sigma=sigma[o])
        mechs[f"pos.{o}"] = LinearMechanism.from_coefficients(np.hstack([np.eye(2), np.eye(2)]), sigma=1e-4)
        abstractions.append(Abstraction(dpos.name, (f"pos.{o}",), 2, Displacement(f"pos.{o}"), dpos))
    return Layer("object", WorldModel(CausalGraph(variables, edges), mechs), tuple(abstractions))


def episode_series(history: History) -> list[dict[str, np.ndarray]]:
    """Per babbling episode the body and object series: ``ee`` (T+1, E), ``touch.o`` (T+1, 1), ``pos.o`` (T+1, 2).

    Sample 0 is the state before the episode's first step (touch 0); sample t + 1 the state
    after step t, with the touch sensed over it. Object positions are the simulator's.
    """
    episode = history.array("episode")
    hand_prev, hand = history.array("hand_prev"), history.array("hand")
    touch, truth_prev, truth = (history.array(k) for k in ("touch", "truth_prev", "truth"))
    out = []
    for e in np.unique(episode):
        rows = np.flatnonzero(episode == e)
        if len(rows) < 3:
            continue
        first = rows[0]
        series = {"ee": np.vstack([hand_prev[first], hand[rows]])}
        for k, o in enumerate(history.objects):
            series[f"touch.{o}"] = np.concatenate([[0.0], touch[rows, k]])[:, None]
            series[f"pos.{o}"] = np.vstack([truth_prev[first, k, :2], truth[rows, k, :2]])
        out.append(series)
    return out


def fit_push_gains(
    hierarchy: Hierarchy, series: Sequence[Mapping[str, np.ndarray]], objects: Sequence[str], ridge: float
) -> tuple[dict[str, np.ndarray], dict[str, float], dict[str, int]]:
    """Ridge fit of ``dpos.o = A_o push.o`` on the bottom-up evidence of ``series`` (module docstring).

    Returns:
        ``(gains, sigma, rows)``: object -> (2, 2) gain, residual sd (m, at least 1 mm) and the
        number of push events fitted on.
    """
    xs: dict[str, list[Tensor]] = {o: [] for o in objects}
    ys: dict[str, list[Tensor]] = {o: [] for o in objects}
    for s in series:
        ev = hierarchy.evidence(s)
        for o in objects:
            n = ev["object"][f"dpos.{o}"].shape[0]
            xs[o].append(ev["event"][f"push.{o}"][:n])
            ys[o].append(ev["object"][f"dpos.{o}"])
    gains, sigma, rows = {}, {}, {}
    for o in objects:
        x = torch.cat(xs[o]).numpy() if xs[o] else np.zeros((0, 2))
        y = torch.cat(ys[o]).numpy() if ys[o] else np.zeros((0, 2))
        hit = np.abs(x).sum(1) > 0
        x, y = x[hit], y[hit]
        a = (y.T @ x + ridge * np.eye(2)) @ np.linalg.inv(x.T @ x + ridge * np.eye(2))
        res = y - x @ a.T
        gains[o] = a
        sigma[o] = max(float(np.sqrt(np.mean(res**2))) if len(x) else 0.0, 1e-3)
        rows[o] = len(x)
    return gains, sigma, rows


def _unit(v: Tensor) -> Tensor:
    return v / v.norm(dim=-1, keepdim=True).clamp_min(1e-9)


def _geometry(
    events: Mapping[str, Tensor], state: Mapping[str, Tensor], gap: float
) -> tuple[str, Tensor, Tensor, Tensor, float]:
    (name,) = [k for k in events if k.startswith("push.")]
    o = name.split(".", 1)[1]
    push = events[name].to(torch.float64)
    p = state[f"pos_prev.{o}"].to(torch.float64)
    return o, push, p, _unit(push), OBJECT_RADIUS[o] + HAND_RADIUS + gap


def make_realise(gap: float) -> Any:
    """The push event's top-down map (module docstring): ``(events, state) -> [via, approach, through]``."""

    def realise(events: Mapping[str, Tensor], state: Mapping[str, Tensor]) -> list[dict[str, Tensor]]:
        o, push, p, u, dist = _geometry(events, state, gap)
        hand = state["ee_prev"].to(torch.float64)
        perp = torch.stack([-u[:, 1], u[:, 0]], -1)
        side = torch.sign(((hand[:, :2] - p) * perp).sum(-1, keepdim=True))
        side = torch.where(side == 0, torch.ones_like(side), side)
        points = (
            p + dist * _unit(side * perp - u),
            p - dist * u,
            p - (_NEAR_FACE[o] + HAND_RADIUS) * u + push.norm(dim=-1, keepdim=True) * u,
        )
        return [{"ee": torch.cat([pt, hand[:, 2:]], -1)} for pt in points]

    return realise


def push_phase(events: Mapping[str, Tensor], state: Mapping[str, Tensor], config: HierarchyConfig) -> int:
    """The current phase (index into :data:`PHASES`) of the first unit from the hand's place.

    ``through`` when the hand is behind the object's near face within ``align`` of the push line
    (and not farther back than the approach point plus 3 cm); ``approach`` when the straight way
    to the approach point keeps the hand clear of the object's circle; else ``via``.
    """
    o, _, p, u, dist = _geometry(events, state, config.gap)
    hand = state["ee_prev"].to(torch.float64)[0, :2]
    p, u = p[0], u[0]
    rel = hand - p
    along = float(rel @ u)
    side = float(rel @ torch.stack([-u[1], u[0]]))
    if abs(side) <= config.align and -dist - 0.03 <= along <= -(_NEAR_FACE[o] + HAND_RADIUS) + 0.005:
        return 2
    a = p - dist * u
    seg = a - hand
    t = float(((p - hand) @ seg) / max(float(seg @ seg), 1e-12))
    closest = hand + min(max(t, 0.0), 1.0) * seg
    clear = float((closest - p).norm()) >= OBJECT_RADIUS[o] + HAND_RADIUS
    return 1 if clear else 0


def pushing_hierarchy(
    model: WorldModel,
    history: History,
    config: HierarchyConfig,
    objects: Sequence[str] = ("box", "ball"),
    seed: int = 0,
) -> tuple[Hierarchy, dict[str, Any]]:
    """The three layers over the agent's fitted ``model``, the push gains fitted on ``history``.

    Returns:
        ``(hierarchy, info)``: ``info`` has per object the fitted ``gain`` (2 x 2), ``sigma`` (m)
        and ``push_rows`` (push events fitted on).
    """
    unknown = sorted(set(objects) - set(_NEAR_FACE))
    if unknown:
        raise ValueError(f"objects {unknown} have no push geometry; expected some of {sorted(_NEAR_FACE)}")
    body, event = body_layer(model), _event_layer(objects, config.contact_threshold)
    kwargs = {
        "object_query": config.object_query,
        "body_query": config.body_query,
        "context_samples": config.context_samples,
        "threshold": config.threshold,
        "seed": seed,
    }
    realise = make_realise(config.gap)
    identity = {o: np.eye(2) for o in objects}
    prior = Hierarchy(
        body,
        event,
        _object_layer(objects, identity, dict.fromkeys(objects, 1e-3), config.max_push),
        realise,
        **kwargs,
    )
    gains, sigma, rows = fit_push_gains(prior, episode_series(history), objects, config.ridge)
    h = Hierarchy(body, event, _object_layer(objects, gains, sigma, config.max_push), realise, **kwargs)
    info = {o: {"gain": gains[o].tolist(), "sigma": sigma[o], "push_rows": rows[o]} for o in objects}
    return h, info
