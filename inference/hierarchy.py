"""A hierarchy of coupled world-model layers and its nested queries (thesis §6.4.1, Eq. 6.2-6.3).

Three layers, each a :class:`models.WorldModel`:

- body (LSML): actuator commands, joints, effector, touch, e.g. ``act -> dq -> q``;
- event (IBEL): abstraction variables over body trajectories (reach, contact, push events);
- object (HOEL): object positions and relations, whose action roots are event variables.

**Bottom-up** (:meth:`Hierarchy.evidence`): the event layer's abstractions Z = h(x_S(t : t + Δt))
(Eq. 6.2) over the body history are the event layer's observed values; the object layer's are
computed over the body history together with those event values (aligned at the window start).

**Top-down** (:meth:`Hierarchy.plan`, Eq. 6.3): X_object^tar -> Z_event^tar -> a*(t).

1. Z_event^tar = argmax_z log p(X_object = X^tar | do(Z_event = z), state): action inference
   (:func:`inference.infer_action`) on the object layer, whose actions are the event variables.
2. ``realise(Z_event^tar, state)``: the event's top-down map (an abstraction's inverse, e.g. a
   motor primitive's trajectory or a push's effector waypoints) gives body-level targets, one
   dict per phase.
3. a*(t) = action inference on the body layer towards the current phase's targets.

At both levels the query runs on the active subgraph G^C (Eq. 6.4-6.7,
:func:`inference.active_subgraph`, :func:`inference.subgraph_model`) of the level's targets,
extracted once per target set from ``context_samples`` draws of the layer's observational
distribution (:meth:`models.WorldModel.sample`, roots from their priors): e.g. only the targeted
object's sites on the object layer, only the arm's sites on the body layer.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import torch
from torch import Tensor

from inference.action import ActionOptions, ActionResult, infer_action
from inference.context import ActiveSubgraph, active_subgraph, subgraph_model
from models.abstraction import Abstraction, abstract
from models.checks import check_float, check_int, check_mapping, describe
from models.world import WorldModel, require_world_model

__all__ = ["HierarchicalPlan", "Hierarchy", "Layer", "LevelQuery"]

#: ``(event targets name -> (N, dim), state name -> (N, dim)) -> body targets per phase``.
Realise = Callable[[Mapping[str, Tensor], Mapping[str, Tensor]], Sequence[Mapping[str, Tensor]]]

LAYERS = ("body", "event", "object")


@dataclass(frozen=True)
class Layer:
    """One layer: its world model and the abstractions that give its observed values bottom-up.

    Attributes:
        name: ``"body"``, ``"event"`` or ``"object"``.
        model: the layer's world model.
        abstractions: Z_k computed over the layer below (none for the body layer); every
            abstraction's variable must be a variable of ``model.graph``.
    """

    name: str
    model: WorldModel
    abstractions: tuple[Abstraction, ...] = ()

    def __post_init__(self) -> None:
        if self.name not in LAYERS:
            raise ValueError(f"layer name {self.name!r} unknown; expected one of {LAYERS}")
        require_world_model(self.model, f"layer {self.name!r} model")
        object.__setattr__(self, "abstractions", tuple(self.abstractions))
        g = self.model.graph
        for a in self.abstractions:
            if not isinstance(a, Abstraction):
                raise ValueError(f"layer {self.name!r}: expected Abstraction instances, got {describe(a)}")
            if a.name not in g or g[a.name].dim != a.variable.dim:
                raise ValueError(
                    f"layer {self.name!r}: abstraction {a.name!r} (dim {a.variable.dim}) is not a variable "
                    f"of the layer's graph of that dim ({list(g.names)})"
                )


@dataclass(frozen=True)
class LevelQuery:
    """Action-inference settings of one level (:func:`inference.infer_action`)."""

    num_steps: int = 100
    options: ActionOptions = field(default_factory=ActionOptions)

    def __post_init__(self) -> None:
        check_int("num_steps", self.num_steps)
        if not isinstance(self.options, ActionOptions):
            raise ValueError(f"options must be an ActionOptions, got {describe(self.options)}")


@dataclass(frozen=True)
class HierarchicalPlan:
    """The nested answer X_object^tar -> Z_event^tar -> a*(t).

    Attributes:
        event_targets: Z_event^tar, event variable -> ``(N, dim)``.
        body_targets: per phase, body variable -> ``(N, dim)`` targets (from ``realise``).
        phase: the phase whose actions were inferred.
        actions: a*(t), action -> ``(N, dim)``.
        object_result, body_result: the two action-inference results.
        contexts: ``"object"`` / ``"body"`` -> the active subgraph each query ran on.
    """

    event_targets: dict[str, Tensor]
    body_targets: tuple[dict[str, Tensor], ...]
    phase: int
    actions: dict[str, Tensor]
    object_result: ActionResult
    body_result: ActionResult
    contexts: dict[str, ActiveSubgraph]


def _state(model: WorldModel, state: Mapping[str, Tensor], skip: Sequence[str]) -> dict[str, Tensor]:
    g = model.graph
    return {k: v for k, v in state.items() if k in g and g.is_root(k) and k not in skip}


class Hierarchy:
    """Body, event and object layers with bottom-up evidence and top-down nested action inference.

    Args:
        body, event, object: the three layers (module docstring). The object layer's action roots
            must be variables of the event layer.
        realise: the event's top-down map to body targets per phase.
        object_query, body_query: action-inference settings per level.
        context_samples: draws of each layer's observational distribution for contextualisation.
        threshold: smallest standardised relevance R_{j->i} of an active edge (Eq. 6.6).
        seed: seeds the context samples and the action inference.
    """

    def __init__(
        self,
        body: Layer,
        event: Layer,
        object: Layer,
        realise: Realise,
        *,
        object_query: LevelQuery | None = None,
        body_query: LevelQuery | None = None,
        context_samples: int = 256,
        threshold: float = 0.01,
        seed: int = 0,
    ) -> None:
        for want, layer in zip(LAYERS, (body, event, object), strict=True):
            if not isinstance(layer, Layer) or layer.name != want:
                raise ValueError(f"the {want} layer must be a Layer named {want!r}, got {describe(layer)}")
        if not callable(realise):
            raise ValueError(f"realise must be callable, got {describe(realise)}")
        events = object.model.graph.actions
        missing = [a for a in events if a not in event.model.graph]
        if not events or missing:
            raise ValueError(
                f"the object layer's action roots {list(events)} must be event-layer variables; "
                f"missing from the event layer: {missing}"
            )
        self.layers = {"body": body, "event": event, "object": object}
        self.realise = realise
        self.queries = {"object": object_query or LevelQuery(), "body": body_query or LevelQuery()}
        self.context_samples = check_int("context_samples", context_samples, minimum=2)
        self.threshold = check_float("threshold", threshold, minimum=0.0)
        self.seed = int(seed)
        self._contexts: dict[tuple[str, tuple[str, ...]], tuple[WorldModel, ActiveSubgraph]] = {}

    # ------------------------------------------------------------------ bottom-up
    def evidence(self, history: Mapping[str, Any], stride: int = 1) -> dict[str, dict[str, Tensor]]:
        """Observed values of the higher layers from a body history (module docstring).

        Args:
            history: body variable name -> ``(T, d)`` (the object layer's abstractions may also
                read object variables given here, e.g. perceived positions).
            stride: steps between window starts.

        Returns:
            ``{"event": name -> (B_e, dim), "object": name -> (B_o, dim)}``.

        Raises:
            models.abstraction.WindowError: a window longer than the history.
        """
        history = check_mapping("history", history)
        event = abstract(history, self.layers["event"].abstractions, stride)
        lengths = [v.shape[0] for v in event.values()]
        n = min(lengths) if lengths else None
        below: dict[str, Any] = {k: (v[:n] if n is not None else v) for k, v in history.items()}
        below.update({k: v[:n] for k, v in event.items()})
        return {"event": event, "object": abstract(below, self.layers["object"].abstractions, stride)}

    # ------------------------------------------------------------------ contextualisation
    def context(self, layer: str, targets: Sequence[str]) -> tuple[WorldModel, ActiveSubgraph]:
        """The active submodel of ``layer`` for ``targets`` (Eq. 6.4), cached per target set."""
        key = (layer, tuple(sorted(targets)))
        if key not in self._contexts:
            model = self.layers[layer].model
            gen = torch.Generator().manual_seed(self.seed)
            samples = model.sample(self.context_samples, gen)
            sub = active_subgraph(model, samples, list(targets), self.threshold)
            self._contexts[key] = (subgraph_model(model, sub), sub)
        return self._contexts[key]

    # ------------------------------------------------------------------ top-down
    def event_targets(
        self, object_target: Mapping[str, Any], state: Mapping[str, Any]
    ) -> tuple[dict[str, Tensor], ActionResult, ActiveSubgraph]:
        """Z_event^tar: action inference on the object layer's active submodel (step 1)."""
        targets = dict(check_mapping("object_target", object_target))
        sub_model, sub = self.context("object", list(targets))
        events = [a for a in sub.graph.actions]
        if not events:
            raise ValueError(f"no event variable reaches the object targets {sorted(targets)}")
        result = self._infer("object", sub_model, state, targets, events)
        return dict(result.actions), result, sub

    def actions(
        self, body_target: Mapping[str, Any], state: Mapping[str, Any]
    ) -> tuple[ActionResult, ActiveSubgraph]:
        """a*(t): action inference on the body layer's active submodel towards ``body_target`` (step 3)."""
        targets = dict(check_mapping("body_target", body_target))
        sub_model, sub = self.context("body", list(targets))
        return self._infer("body", sub_model, state, targets, list(sub.graph.actions)), sub

    def _infer(
        self, level: str, model: WorldModel, state: Mapping[str, Any], targets: dict, actions: list[str]
    ) -> ActionResult:
        """Action inference on one level's active submodel with that level's query settings."""
        q = self.queries[level]
        return infer_action(
            model,
            _state(model, state, actions) or None,
            targets,
            actions=actions,
            num_steps=q.num_steps,
            options=q.options,
            seed=self.seed,
        )

    def plan(
        self, object_target: Mapping[str, Any], state: Mapping[str, Any], phase: int = 0
    ) -> HierarchicalPlan:
        """The nested query X_object^tar -> Z_event^tar -> a*(t) (Eq. 6.3).

        Args:
            object_target: object-layer variable -> ``(N, dim)`` target values.
            state: name -> ``(N, dim)`` current values of the roots of both layers.
            phase: which of the realised phases to infer actions for.

        Raises:
            ValueError: a phase that the realisation does not have, or bad targets or state.
        """
        state = {k: torch.as_tensor(v) for k, v in check_mapping("state", state).items()}
        events, obj_result, obj_sub = self.event_targets(object_target, state)
        phases = tuple(dict(p) for p in self.realise(events, state))
        phase = check_int("phase", phase, minimum=0)
        if phase >= len(phases):
            raise ValueError(
                f"phase {phase} does not exist; the event was realised in {len(phases)} phase(s)"
            )
        body_result, body_sub = self.actions(phases[phase], state)
        return HierarchicalPlan(
            events,
            phases,
            phase,
            dict(body_result.actions),
            obj_result,
            body_result,
            {"object": obj_sub, "body": body_sub},
        )
