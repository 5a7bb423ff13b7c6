"""The built-in grounded predicates: near, touch, reachable, moving, on, left_of (thesis Eq. 6.9).

Each is a graded map over the variables its argument constants bind, evaluated on every sample
of those variables (so their uncertainty is propagated; the evaluator averages). The spatial
ones are the torch twins of :func:`pal.perception.grounding.grade`, on a constant's geometry:

- ``position`` variable p (``(..., 2)`` or ``(..., 3)``, m; x right, y away, z up), footprint a
  square of half-width ``radius`` (attribute, m, default 0), ``height`` (attribute, m, default
  0; bottom = z - height/2, top = z + height/2), position uncertainty ``sigma`` (attribute, m,
  default ``config.position_floor``); ``extent = max(2 radius, height)``.

With Phi the standard normal CDF and ``s_ab = sqrt(sigma_a² + sigma_b²)``:

- ``left_of(a, b) = Phi((x_b - x_a) / sqrt(s_ab² + ((r_a + r_b) / 2)²))``;
- ``near(a, b) = Phi((d - gap) / (0.25 d + s_ab))``, gap the distance between the footprints,
  and between the 3-D boxes when both positions are 3-D and both constants have a ``height``;
  ``d = near_distance``;
- ``on(a, b) = Phi((tol - |bottom_a - top_b|) / (tol / 2 + s_ab)) * overlap(a, b)`` when
  z_a > z_b, else 0 (3-D positions);
- ``touch(a, b)``: with a ``contact`` variable c bound by b (else by a): ``clamp(c, 0, 1)`` (a
  touch strength, or a contact count: 1 from one contact on), or
  ``Phi((c - c0) / (c0 / 2))`` with ``touch_threshold = c0``; otherwise the surface gap of
  spheres of radius ``radius``, ``Phi((touch_gap - gap) / (s_ab / 2 + 0.005))``;
- ``reachable(h, o) = Phi((reach_h + r_o - |p_o - base_h|) / (0.25 near_distance + s_ho))``,
  ``reach`` an attribute of h (m), ``base`` its variable or attributes ``base_x``, ``base_y``,
  ``base_z`` (default 0);
- ``moving(o) = Phi((|p_o(t) - p_o(t-1)| - v0) / (0.25 v0 + sqrt(2) sigma_o))`` over the last step
  (window 1), ``v0 = moving_distance`` (m per step).

Positions of different dims (a 3-D hand and a 2-D object) are compared on their common
components.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping

import torch
from torch import Tensor
from torch.special import ndtr

from pal.language.predicates import roles_support
from pal.language.signature import Constant, LanguageError, PredicateDef
from pal.perception.grounding import GroundingConfig

__all__ = ["builtin_predicates"]

PLACES = "object|body_part"

#: A graded map: ``(values, constants) -> grade``.
Ground = Callable[[Mapping[str, Tensor], tuple[Constant, ...]], Tensor]


def _attr(c: Constant, key: str, default: float | None = None, what: str = "") -> float:
    if key in c.attributes:
        return float(c.attributes[key])
    if default is None:
        raise LanguageError(
            f"{what}: {c.sort} {c.name!r} needs the attribute {key!r}; it has {sorted(c.attributes)}"
        )
    return default


def _pos(values: Mapping[str, Tensor], c: Constant) -> Tensor:
    return values[c.variable("position")]


def _common(pa: Tensor, pb: Tensor, k: int | None = None) -> tuple[Tensor, Tensor]:
    d = min(pa.shape[-1], pb.shape[-1]) if k is None else k
    return pa[..., :d], pb[..., :d]


def _sab(a: Constant, b: Constant, floor: float) -> float:
    """``s_ab``: the combined position uncertainty of two constants, m."""
    return math.hypot(_attr(a, "sigma", floor), _attr(b, "sigma", floor))


def _footprint_gap(pa: Tensor, pb: Tensor, ra: float, rb: float) -> Tensor:
    """Distance between two square footprints of half-widths ``ra``, ``rb`` (horizontal components)."""
    pa, pb = _common(pa, pb, 2)
    return (((pa - pb).abs() - (ra + rb)).clamp_min(0.0) ** 2).sum(-1).sqrt()


def _placement(config: GroundingConfig) -> tuple[Ground, Ground, Ground]:
    """The graded maps of left_of, near and on (module docstring)."""
    floor = config.position_floor

    def left_of(values: Mapping[str, Tensor], constants: tuple[Constant, ...]) -> Tensor:
        a, b = constants
        pa, pb = _pos(values, a), _pos(values, b)
        ra, rb = _attr(a, "radius", 0.0), _attr(b, "radius", 0.0)
        s = math.sqrt(_sab(a, b, floor) ** 2 + ((ra + rb) / 2.0) ** 2)
        return ndtr((pb[..., 0] - pa[..., 0]) / s)

    def near(values: Mapping[str, Tensor], constants: tuple[Constant, ...]) -> Tensor:
        a, b = constants
        pa, pb = _pos(values, a), _pos(values, b)
        ra, rb = _attr(a, "radius", 0.0), _attr(b, "radius", 0.0)
        gap = _footprint_gap(pa, pb, ra, rb)
        if pa.shape[-1] >= 3 and pb.shape[-1] >= 3 and "height" in a.attributes and "height" in b.attributes:
            half = (_attr(a, "height", 0.0) + _attr(b, "height", 0.0)) / 2.0
            vertical = ((pa[..., 2] - pb[..., 2]).abs() - half).clamp_min(0.0)
            gap = torch.sqrt(gap**2 + vertical**2)
        d = config.near_distance
        return ndtr((d - gap) / (0.25 * d + _sab(a, b, floor)))

    def on(values: Mapping[str, Tensor], constants: tuple[Constant, ...]) -> Tensor:
        a, b = constants
        pa, pb = _pos(values, a), _pos(values, b)
        if pa.shape[-1] < 3 or pb.shape[-1] < 3:
            raise LanguageError(
                f"on({a.name}, {b.name}) needs 3-D positions (z up); got dims {pa.shape[-1]} and {pb.shape[-1]}"
            )
        ra, rb = _attr(a, "radius", 0.0), _attr(b, "radius", 0.0)
        ha, hb = _attr(a, "height", 0.0), _attr(b, "height", 0.0)
        tol = config.on_tolerance
        bottom, top = pa[..., 2] - ha / 2.0, pb[..., 2] + hb / 2.0
        contact = ndtr((tol - (bottom - top).abs()) / (tol / 2.0 + _sab(a, b, floor)))
        lo = torch.maximum(pa[..., :2] - ra, pb[..., :2] - rb)
        hi = torch.minimum(pa[..., :2] + ra, pb[..., :2] + rb)
        overlap = (hi - lo).clamp_min(0.0).prod(-1) / max(2 * ra, 1e-3) ** 2
        return torch.where(pa[..., 2] > pb[..., 2], contact * overlap, torch.zeros_like(contact)).clamp(
            0.0, 1.0
        )

    return left_of, near, on


def _contact_of(a: Constant, b: Constant) -> str | None:
    """The contact variable bound by b, else by a, or None."""
    for c in (b, a):
        if "contact" in c.variables:
            return c.variables["contact"]
    return None


def _touch_support(constants: tuple[Constant, ...]) -> tuple[str, ...]:
    """The contact variable when there is one, else both positions."""
    v = _contact_of(*constants)
    return (v,) if v is not None else roles_support("position")(constants)


def _touch(config: GroundingConfig, touch_threshold: float | None) -> Ground:
    """The graded map of touch (module docstring)."""
    floor = config.position_floor

    def touch(values: Mapping[str, Tensor], constants: tuple[Constant, ...]) -> Tensor:
        a, b = constants
        v = _contact_of(a, b)
        if v is not None:
            c = values[v][..., 0]
            if touch_threshold is None:
                return c.clamp(0.0, 1.0)
            return ndtr((c - touch_threshold) / (touch_threshold / 2.0))
        pa, pb = _common(_pos(values, a), _pos(values, b))
        gap = ((pa - pb).norm(dim=-1) - _attr(a, "radius", 0.0) - _attr(b, "radius", 0.0)).clamp_min(0.0)
        return ndtr((config.touch_gap - gap) / (_sab(a, b, floor) * 0.5 + 0.005))

    return touch


def _reach_support(constants: tuple[Constant, ...]) -> tuple[str, ...]:
    """Both positions and the hand's base variable, if it has one."""
    h, o = constants
    base = (h.variables["base"],) if "base" in h.variables else ()
    return (h.variable("position", "reachable"), o.variable("position", "reachable"), *base)


def _reachable(config: GroundingConfig) -> Ground:
    """The graded map of reachable (module docstring)."""
    floor = config.position_floor

    def reachable(values: Mapping[str, Tensor], constants: tuple[Constant, ...]) -> Tensor:
        h, o = constants
        reach = _attr(h, "reach", what=f"reachable({h.name}, {o.name})")
        po = _pos(values, o)
        if "base" in h.variables:
            base = values[h.variables["base"]]
        else:
            xyz = [_attr(h, f"base_{k}", 0.0) for k in "xyz"][: po.shape[-1]]
            base = torch.tensor(xyz, dtype=po.dtype)
        po, base = _common(po, base)
        dist = (po - base).norm(dim=-1)
        s = 0.25 * config.near_distance + _sab(h, o, floor)
        return ndtr((reach + _attr(o, "radius", 0.0) - dist) / s)

    return reachable


def _moving(config: GroundingConfig, moving_distance: float) -> Ground:
    """The graded map of moving over the last step (module docstring)."""
    floor = config.position_floor

    def moving(values: Mapping[str, Tensor], constants: tuple[Constant, ...]) -> Tensor:
        (o,) = constants
        path = _pos(values, o)  # (..., 2, d)
        step = (path[..., -1, :] - path[..., -2, :]).norm(dim=-1)
        s = 0.25 * moving_distance + math.sqrt(2.0) * _attr(o, "sigma", floor)
        return ndtr((step - moving_distance) / s)

    return moving


def builtin_predicates(
    config: GroundingConfig | None = None,
    *,
    moving_distance: float = 0.005,
    touch_threshold: float | None = None,
) -> tuple[PredicateDef, ...]:
    """near, touch, reachable, moving, on, left_of with the perception defaults (module docstring).

    Args:
        config: (default ``GroundingConfig()``) the scales of :mod:`pal.perception.grounding` (near_distance, on_tolerance,
            touch_gap, position_floor), metres.
        moving_distance: v0, the displacement per step that counts as moving, m.
        touch_threshold: c0 for a contact variable; None grades ``clamp(c, 0, 1)``.
    """
    if not moving_distance > 0:
        raise LanguageError(f"moving_distance must be > 0 m, got {moving_distance!r}")
    if touch_threshold is not None and not touch_threshold > 0:
        raise LanguageError(f"touch_threshold must be > 0 or None, got {touch_threshold!r}")
    config = GroundingConfig() if config is None else config
    left_of, near, on = _placement(config)
    pos = roles_support("position")
    return (
        PredicateDef("near", (PLACES, PLACES), pos, near, doc="a and b are within about an object's size"),
        PredicateDef(
            "touch", (PLACES, PLACES), _touch_support, _touch(config, touch_threshold), doc="a touches b"
        ),
        PredicateDef(
            "reachable",
            ("body_part", PLACES),
            _reach_support,
            _reachable(config),
            doc="o lies within h's reach",
        ),
        PredicateDef(
            "moving",
            (PLACES,),
            pos,
            _moving(config, moving_distance),
            window=1,
            doc="o moved over the last step",
        ),
        PredicateDef("on", (PLACES, PLACES), pos, on, doc="a rests on top of b"),
        PredicateDef("left_of", (PLACES, PLACES), pos, left_of, doc="a is left of b (smaller x)"),
    )
