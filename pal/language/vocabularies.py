"""The signatures of the two worlds: constants bound to the agent world model's variables.

Pushing world (:func:`pal.agent.pushing_spec`): ``hand`` (body part: ``ee``, joints ``q``),
``box`` and ``ball`` (objects: ``pos.o``, ``contact.o``, ``dpos.o``, ``rel.o``). Pusher-v5
(:func:`pal.agent.pusher_spec`): ``fingertip`` (``ee``, ``q``), ``object`` (``pos.object``,
``dpos.object``, ``rel.object``) and ``goal``, the object's goal marker (``goal.object``, a disc
of 8 cm radius; sensed, not a world-model variable, so a model world holds it:
``ModelWorld(model, held=("goal.object",))``). Actions ``act`` (:mod:`pal.agent.graph`).

Action terms:

- ``hold(h)``: keep the start's servo targets (pushing world: the joint angles; Pusher-v5,
  torque driven: zero torques), a fixed sequence;
- ``reach(h, o)``: action inference bringing ``ee`` to the object's position;
- ``push(h, o)``: action inference bringing the object's position ``push_distance`` m further
  along the hand -> object direction.
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
from torch import Tensor

from pal.checks import check_float
from pal.language.actions import CompileContext, fixed_action_term, inferred_action_term
from pal.language.builtins import builtin_predicates
from pal.language.signature import ActionTermDef, Constant, Signature
from pal.perception.grounding import GroundingConfig

__all__ = ["pusher_signature", "pushing_signature"]

PLACES = "object|body_part"
#: Radius of Pusher-v5's goal marker (a thin cylinder), m.
GOAL_RADIUS = 0.08


def _check(horizon: int | None, push_distance: float) -> None:
    if horizon is not None and (isinstance(horizon, bool) or not isinstance(horizon, int) or horizon < 1):
        raise ValueError(f"horizon must be None or an int >= 1 (steps), got {horizon!r}")
    check_float("push_distance", push_distance, 0.0, open_low=True)


def _object(name: str, contact: bool, **attributes: float) -> Constant:
    roles = {"position": f"pos.{name}", "displacement": f"dpos.{name}", "relative": f"rel.{name}"}
    if contact:
        roles["contact"] = f"contact.{name}"
    return Constant(name, "object", roles, attributes)


def _hold(torque: bool) -> ActionTermDef:
    def fn(context: CompileContext, constants: tuple[Constant, ...]) -> Mapping[str, Tensor]:
        q = context.situations.values[constants[0].variable("joints", "hold")]
        return {"act": torch.zeros_like(q) if torque else q}

    return fixed_action_term("hold", ("body_part",), ("act",), fn, doc="keep the current servo targets")


def _reach(horizon: int | None) -> ActionTermDef:
    def target(context: CompileContext, constants: tuple[Constant, ...]) -> Mapping[str, Tensor]:
        h, o = constants
        ee = context.situations.values[h.variable("position", "reach")]
        pos = context.situations.values[o.variable("position", "reach")]
        goal = ee.clone()
        k = min(ee.shape[-1], pos.shape[-1])
        goal[:, :k] = pos[:, :k]
        return {h.variable("position", "reach"): goal}

    return inferred_action_term(
        "reach",
        ("body_part", "object"),
        ("act",),
        lambda c: (c[0].variable("position"), c[1].variable("position")),
        target,
        horizon,
        doc="bring the hand to the object",
    )


def _push(horizon: int | None, distance: float) -> ActionTermDef:
    def target(context: CompileContext, constants: tuple[Constant, ...]) -> Mapping[str, Tensor]:
        h, o = constants
        ee = context.situations.values[h.variable("position", "push")]
        pos = context.situations.values[o.variable("position", "push")]
        k = min(ee.shape[-1], pos.shape[-1], 2)
        d = pos[:, :k] - ee[:, :k]
        goal = pos.clone()
        goal[:, :k] = pos[:, :k] + distance * d / d.norm(dim=-1, keepdim=True).clamp_min(1e-6)
        return {o.variable("position", "push"): goal}

    return inferred_action_term(
        "push",
        ("body_part", "object"),
        ("act",),
        lambda c: (c[0].variable("position"), c[1].variable("position")),
        target,
        horizon,
        doc="push the object away from the hand",
    )


def pushing_signature(
    horizon: int | None = None, push_distance: float = 0.05, grounding: GroundingConfig | None = None
) -> Signature:
    """The pushing world's signature (module docstring).

    Args:
        horizon: steps of the inferred action terms (None: the term's default).
        push_distance: how far ``push`` aims past the object, m.
        grounding: the built-ins' scales (:func:`pal.language.builtins.builtin_predicates`); its
            ``position_floor`` is the position uncertainty of every constant, m. The default (1 cm)
            is that of perceived positions; worlds reporting true positions want less.
    """
    from pal.sim.pushing import BOX_HALF, OBJECT_RADIUS

    _check(horizon, push_distance)

    hand = Constant("hand", "body_part", {"position": "ee", "joints": "q"}, {"reach": 0.25})
    box = _object("box", True, radius=max(BOX_HALF[:2]), height=2 * BOX_HALF[2])
    ball = _object("ball", True, radius=OBJECT_RADIUS["ball"], height=2 * OBJECT_RADIUS["ball"])
    return Signature(
        (hand, box, ball),
        builtin_predicates(grounding),
        (_hold(False), _reach(horizon), _push(horizon, push_distance)),
    )


def pusher_signature(
    horizon: int | None = None, push_distance: float = 0.05, grounding: GroundingConfig | None = None
) -> Signature:
    """Pusher-v5's signature (module docstring); the arguments as for :func:`pushing_signature`."""
    _check(horizon, push_distance)
    tip = Constant("fingertip", "body_part", {"position": "ee", "joints": "q"})
    obj = _object("object", False, radius=0.05)
    goal = Constant("goal", "object", {"position": "goal.object"}, {"radius": GOAL_RADIUS})
    return Signature(
        (tip, obj, goal),
        builtin_predicates(grounding),
        (_hold(True), _reach(horizon), _push(horizon, push_distance)),
    )
