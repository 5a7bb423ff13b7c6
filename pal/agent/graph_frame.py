"""The objects' sites in the push frame (``ModelConfig.object_frame = "push"``): pushes learnt once for every direction.

Pushing an object on a level table looks the same from every horizontal direction
(:mod:`models.push_frame`). In the world frame (the default) the learned ``contact.o`` and
``dpos.o`` read the effector's position relative to the object as it is, so each push direction
must be learnt from its own data; a model trained on a few placements of object and goal meets
new directions at every new placement. In the push frame they read their parents turned so that
the effector before the step lies on the +x axis, and ``dpos.o`` is the displacement in that
frame. With P points of the body that touch objects (:attr:`pal.agent.spec.EnvSpec.effector_points`,
e.g. a claw's ends, placed by the MJCF's kinematics) these enter too, since the effector's
position alone does not say where the body touches the object. Per object o, replacing the
world frame's parents of ``contact.o`` and ``dpos.o``::

    q_prev -> pts_prev,  q -> pts                        the P points before and after (MJCF, fixed)
    pts_prev, pos_prev.o -> prel_prev.o                  prel = pts - [pos, 0] per point (fixed)
    pts, pos_prev.o -> prel.o
    rel_prev.o, rel.o [, prel_prev.o, prel.o] [, vel_prev.o] -> local.o     all turned by -phi (fixed,
                                                         phi the direction of rel_prev.o in x-y)
    local.o -> contact.o                                 (learned)
    contact.o, local.o -> dpos.o                         displacement in the push frame (learned)
    rel_prev.o, dpos.o -> vel.o                          turned back by +phi (fixed)
    pos_prev.o, rel_prev.o, dpos.o -> pos.o              pos = pos_prev + vel, in one site (fixed)

and ``vel_prev.o`` is the lag of ``vel.o`` (the world-frame displacement). The training columns
follow from the recorded ones (:func:`frame_columns`): ``vel.o`` is the recorded displacement and
``dpos.o`` that displacement turned by ``-phi``; the fixed sites are computed by their mechanisms.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import torch

from models import (
    CausalGraph,
    FromPushFrameMechanism,
    LinearMechanism,
    PushFrameMechanism,
    Role,
    Variable,
    WorldModel,
)
from models.push_frame import frame_angle, to_push_frame
from pal.agent.spec import EnvSpec

__all__ = [
    "FRAMES",
    "POINT_SITES",
    "displacement_site",
    "frame_columns",
    "frame_fixed_parents",
    "frame_learned_parents",
    "frame_mechanisms",
    "frame_object_variables",
    "point_variables",
    "world_displacement",
]

#: The frames of the objects' learned sites.
FRAMES = ("world", "push")
#: The sites of the body's points, before and after the step (computed from q_prev and q).
POINT_SITES = ("pts_prev", "pts")


def displacement_site(graph: CausalGraph, o: str) -> str:
    """The site of object ``o``'s world-frame displacement over the step: ``vel.o`` in the push frame, else ``dpos.o``."""
    return f"vel.{o}" if f"vel.{o}" in graph else f"dpos.{o}"


def world_displacement(
    graph: CausalGraph, mean: Mapping[str, torch.Tensor], scale: Mapping[str, torch.Tensor], o: str
) -> tuple[torch.Tensor, torch.Tensor]:
    """Object ``o``'s one-step displacement in the world frame: mean and sd ``(..., d)``, m.

    ``mean`` and ``scale`` are a model's ``predict`` and ``predict_scale`` (each site's sd at its
    parents). In the push frame ``vel.o``'s own sd is its fixed definition's, so the sd is that of
    ``dpos.o`` turned back: per component ``var_x = c^2 v_x + s^2 v_y``, ``var_y = s^2 v_x + c^2 v_y``
    with ``(c, s)`` the frame's angle (independent components), other components as they are.
    """
    if displacement_site(graph, o) == f"dpos.{o}":
        return mean[f"dpos.{o}"], scale[f"dpos.{o}"]
    rel = mean[f"rel_prev.{o}"]
    c, s = frame_angle(rel, torch.zeros_like(rel[..., :2]))
    var = scale[f"dpos.{o}"].pow(2)
    vx, vy = var[..., :1], var[..., 1:2]
    turned = torch.cat([c.pow(2) * vx + s.pow(2) * vy, s.pow(2) * vx + c.pow(2) * vy, var[..., 2:]], -1)
    return mean[f"vel.{o}"], turned.sqrt()


def point_variables(spec: EnvSpec) -> list[Variable]:
    """``pts_prev``, ``pts`` (3 P, m) when the spec has effector points, else none."""
    p = len(spec.effector_points)
    if not p:
        return []
    return [
        Variable(
            "pts_prev", Role.LATENT, 3 * p, unit="m", description="the body's contact points before the step"
        ),
        Variable("pts", Role.LATENT, 3 * p, unit="m", description="the body's contact points after the step"),
    ]


def frame_object_variables(spec: EnvSpec, o: str) -> list[Variable]:
    """``prel_prev.o``, ``prel.o`` (with points), ``local.o`` and ``vel.o`` of the module docstring."""
    d, e, p = spec.object(o).dim, spec.effector.dim, len(spec.effector_points)  # type: ignore[union-attr]
    out = []
    if p:
        out += [
            Variable(
                f"prel_prev.{o}",
                Role.LATENT,
                3 * p,
                unit="m",
                description="the body's points relative to the object, before",
            ),
            Variable(
                f"prel.{o}",
                Role.LATENT,
                3 * p,
                unit="m",
                description="the body's points relative to the object, after",
            ),
        ]
    width = 2 * e + 2 * 3 * p + (d if spec.object_momentum else 0)
    out += [
        Variable(
            f"local.{o}",
            Role.LATENT,
            width,
            unit="m",
            description="the object's surroundings in its push frame",
        ),
        Variable(
            f"vel.{o}", Role.LATENT, d, unit="m", description="displacement over the step (world frame)"
        ),
    ]
    return out


def frame_learned_parents(spec: EnvSpec, o: str, contact: bool) -> dict[str, tuple[str, ...]]:
    """The learned sites' parents in the push frame."""
    out: dict[str, tuple[str, ...]] = {}
    if contact:
        out[f"contact.{o}"] = (f"local.{o}",)
    out[f"dpos.{o}"] = ((f"contact.{o}",) if contact else ()) + (f"local.{o}",)
    return out


def frame_fixed_parents(spec: EnvSpec) -> dict[str, tuple[str, ...]]:
    """The fixed relations of the push frame (they replace ``pos.o``'s parents)."""
    points = bool(spec.effector_points)
    out: dict[str, tuple[str, ...]] = {"pts_prev": ("q_prev",), "pts": ("q",)} if points else {}
    for o in spec.object_names:
        if points:
            out[f"prel_prev.{o}"] = ("pts_prev", f"pos_prev.{o}")
            out[f"prel.{o}"] = ("pts", f"pos_prev.{o}")
        around = (f"prel_prev.{o}", f"prel.{o}") if points else ()
        momentum = (f"vel_prev.{o}",) if spec.object_momentum else ()
        out[f"local.{o}"] = (f"rel_prev.{o}", f"rel.{o}", *around, *momentum)
        out[f"vel.{o}"] = (f"rel_prev.{o}", f"dpos.{o}")
        out[f"pos.{o}"] = (f"pos_prev.{o}", f"rel_prev.{o}", f"dpos.{o}")
    return out


def _relative_points(points: int, d: int, sigma: float) -> LinearMechanism:
    """``prel = pts - tile([pos, 0])``: parents ``[pts (3 P), pos (d)]``."""
    weight = torch.zeros(3 * points, 3 * points + d)
    weight[:, : 3 * points] = torch.eye(3 * points)
    for k in range(points):
        weight[3 * k : 3 * k + min(d, 3), 3 * points : 3 * points + min(d, 3)] = -torch.eye(min(d, 3))
    return LinearMechanism.from_coefficients(weight, sigma=sigma)


def frame_mechanisms(
    spec: EnvSpec, graph: CausalGraph, sigma: float, position_sigma: float
) -> dict[str, object]:
    """The fixed mechanisms of :func:`frame_fixed_parents` except ``pts_prev``, ``pts`` (known laws of the MJCF).

    A mechanism reads its parents concatenated in the graph's declaration order, so the layouts
    are taken from ``graph`` (e.g. ``vel_prev.o``, a lag root, comes before ``rel_prev.o``).

    Raises:
        ValueError: a site whose parents are not those of :func:`frame_fixed_parents` in an order
            the mechanism reads.
    """
    e, p = spec.effector.dim, len(spec.effector_points)  # type: ignore[union-attr]
    out: dict[str, object] = {}
    for o in spec.object_names:
        d = spec.object(o).dim
        if p:
            _check_order(graph, f"prel_prev.{o}", ("pts_prev", f"pos_prev.{o}"))
            _check_order(graph, f"prel.{o}", ("pts", f"pos_prev.{o}"))
            out[f"prel_prev.{o}"] = _relative_points(p, d, sigma)
            out[f"prel.{o}"] = _relative_points(p, d, sigma)
        parents = graph.parents(f"local.{o}")
        if set(parents) != set(frame_fixed_parents(spec)[f"local.{o}"]):
            raise ValueError(f"local.{o} has parents {list(parents)}, not those of the push frame")
        # each body point is its own 3-vector; every other parent is one vector
        sizes = [[3] * p if n.startswith(("prel_prev.", "prel.")) else [graph[n].dim] for n in parents]
        reference = sum(len(v) for v in sizes[: parents.index(f"rel_prev.{o}")])
        vectors = [v for group in sizes for v in group]
        out[f"local.{o}"] = PushFrameMechanism(vectors, sigma=sigma, reference=reference)
        _check_order(graph, f"vel.{o}", (f"rel_prev.{o}", f"dpos.{o}"))
        _check_order(graph, f"pos.{o}", (f"pos_prev.{o}", f"rel_prev.{o}", f"dpos.{o}"))
        out[f"vel.{o}"] = FromPushFrameMechanism(e, d, sigma=sigma)
        out[f"pos.{o}"] = FromPushFrameMechanism(e, d, sigma=position_sigma, base=True)
    return out


def _check_order(graph: CausalGraph, site: str, expected: tuple[str, ...]) -> None:
    """Refuse a fixed site whose parents the mechanism would read in another layout."""
    if graph.parents(site) != expected:
        raise ValueError(
            f"{site} has parents {list(graph.parents(site))}; its mechanism reads {list(expected)}"
        )


def frame_columns(model: WorldModel, cols: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Training columns for a push-frame model from recorded ones (module docstring); others pass through.

    ``vel.o`` takes the recorded (world-frame) ``dpos.o``, ``dpos.o`` becomes it turned by ``-phi``,
    and every fixed site of the push frame missing from ``cols`` is computed by its mechanism from
    its parents, in topological order. Columns of a world-frame model are returned unchanged.
    """
    graph = model.graph
    out = dict(cols)
    objects = [n.split(".", 1)[1] for n in graph.names if n.startswith("local.")]
    if not objects:
        return out
    for o in objects:
        if f"dpos.{o}" in out and f"vel.{o}" not in out:
            world = torch.as_tensor(out[f"dpos.{o}"], dtype=torch.float64)
            rel = torch.as_tensor(out[f"rel_prev.{o}"], dtype=torch.float64)
            c, s = frame_angle(rel, torch.zeros_like(rel[..., :2]))
            out[f"vel.{o}"] = np.asarray(out[f"dpos.{o}"])
            out[f"dpos.{o}"] = to_push_frame(world, c, s).numpy().astype(np.asarray(out[f"vel.{o}"]).dtype)
    computed = ("pts_prev", "pts", "prel_prev.", "prel.", "local.")
    for name in graph.non_roots:
        if name in out or not name.startswith(computed):
            continue
        parents = graph.parents(name)
        if not all(p in out for p in parents):
            continue
        x = torch.cat([torch.as_tensor(out[p], dtype=model.dtype) for p in parents], -1)
        with torch.no_grad():
            out[name] = model.mechanism(name)(x).numpy().astype(np.float32)
    return out
