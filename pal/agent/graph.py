"""The world model built from an :class:`~pal.agent.spec.EnvSpec`: a generalised pushing graph.

Arm (J joints, A actions; ``v`` only with sensed velocities, ``ee`` only with an effector)::

    act, q_prev [, v_prev] -> dq            joint motion over the step (learned)
    q_prev, dq -> q                          q = q_prev + dq (fixed)
    act, q_prev, v_prev -> v                 joint velocity after the step (learned)
    q_prev, dq -> dee                        effector motion (learned kinematics)
    ee_prev, dee -> ee                       ee = ee_prev + dee (fixed)

Per object o (position d-D, m)::

    ee_prev, pos_prev.o -> rel_prev.o        rel = ee - [pos, 0]: the effector relative to the
    ee, pos_prev.o -> rel.o                  object (fixed), before and after the arm's move
    rel_prev.o, rel.o -> contact.o           contact (learned; with touch sensing, or "gated")
    [contact.o,] rel_prev.o, rel.o [, vel_prev.o] -> dpos.o      displacement (learned)
    pos_prev.o, dpos.o -> pos.o              pos = pos_prev + dpos (fixed)
    pos.o -> meas.o                          perceived position (measurement site, perceived objects)

The displacement has two forms (:attr:`pal.agent.config.ModelConfig.displacement`). ``"gated"``
(the default): ``contact.o`` is a Bernoulli switch of every object, ``P(contact.o = 1) =
sigmoid(g(rel_prev.o, rel.o))`` from the effector's proximity, and ``dpos.o`` a
:class:`models.GatedMechanism`: ``Normal(0, position_sigma)`` without contact (the measurement
floor: the object rests), the smooth form's mechanism with contact, trained on the contact rows
only. ``"smooth"``: ``dpos.o ~ Normal(f(pa), sigma(pa))``, one smooth mechanism, and
``contact.o`` (only with touch sensing) a continuous contact strength, the sensed touch in
[0, 1]. The switch's label (:func:`contact_rule`): with touch sensing it is observed, 1 when any
touch was sensed over the step; without (Gymnasium's Pusher-v5) it is derived from the data,
1 when the object moved more than its noise floor over the step, ``||dpos.o|| >
MOVED_SIGMAS * position_sigma`` (3 mm by default). It is a training label only: in state
inference and planning the switch is latent there, enumerated in state inference, and
marginalised in the planner's expected prediction: ``predict(noise="expected")`` gives
``dpos.o`` the mixture mean ``P(contact) f_on + (1 - P(contact)) * 0``, smooth in the actions
(:mod:`models.gated`), while ``contact.o`` itself takes its mode.

``vel_prev.o`` (the previous displacement) enters with ``spec.object_momentum``. The fixed
relations are linear mechanisms with known coefficients (:meth:`models.LinearMechanism.from_coefficients`),
so the learned mechanisms see the push in the object's frame of reference: a push learnt in one
place applies everywhere. ``parents`` replaces the parent sets of learned sites (e.g. learnt
with :func:`discover_parents`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Any

import numpy as np
import torch

from inference import discover
from models import (
    BernoulliMechanism,
    CausalGraph,
    EnsembleMechanism,
    GatedMechanism,
    HeteroscedasticMechanism,
    LinearMechanism,
    MLPMechanism,
    Role,
    Variable,
    WorldModel,
)
from pal.agent.config import ModelConfig
from pal.agent.graph_frame import (
    FRAMES,
    POINT_SITES,
    frame_fixed_parents,
    frame_learned_parents,
    frame_mechanisms,
    frame_object_variables,
    point_variables,
)
from pal.agent.spec import EnvSpec

__all__ = [
    "FIXED_SIGMA",
    "MOVED_SIGMAS",
    "blanket",
    "build_graph",
    "build_model",
    "contact_rule",
    "discover_parents",
    "learned_sites",
    "restrict",
]

#: Residual sd of the fixed relations (q, ee, rel): they are definitions, not predictions.
FIXED_SIGMA = 1e-4
#: The moved rule's noise floor in units of ``position_sigma``: without touch sensing an object is
#: labelled in contact over a step when it moved more than ``MOVED_SIGMAS * position_sigma``.
MOVED_SIGMAS = 3.0


def contact_rule(spec: EnvSpec, config: ModelConfig) -> tuple[str, float]:
    """``(rule, floor)`` of the ``contact.o`` column (:func:`pal.agent.history.contact_label`).

    Smooth: the sensed touch strength. Gated: the touch as a 0/1 switch with touch sensing, else
    the moved rule with floor ``MOVED_SIGMAS * position_sigma`` (module docstring).
    """
    if config.displacement == "smooth":
        return "strength", 0.0
    if spec.touch is not None:
        return "touch", 0.0
    return "moved", MOVED_SIGMAS * config.position_sigma


def _has_contact(spec: EnvSpec, displacement: str) -> bool:
    if displacement not in ("smooth", "gated"):
        raise ValueError(f"displacement {displacement!r} unknown; expected one of ['smooth', 'gated']")
    return spec.touch is not None or displacement == "gated"


def _object_sites(spec: EnvSpec, o: str, displacement: str, frame: str = "world") -> list[Variable]:
    d, e = spec.object(o).dim, spec.effector.dim
    out = [
        Variable(
            f"pos_prev.{o}",
            Role.OBSERVED,
            d,
            unit="m",
            lag=1,
            lag_of=f"pos.{o}",
            description="position before the step",
        )
    ]
    if spec.object_momentum:
        out.append(
            Variable(
                f"vel_prev.{o}",
                Role.OBSERVED,
                d,
                unit="m",
                lag=1,
                lag_of=f"vel.{o}" if frame == "push" else f"dpos.{o}",
                description="previous displacement",
            )
        )
    out += [
        Variable(
            f"rel_prev.{o}", Role.LATENT, e, unit="m", description="effector relative to the object, before"
        ),
        Variable(
            f"rel.{o}",
            Role.LATENT,
            e,
            unit="m",
            description="effector relative to the object, after the arm's move",
        ),
    ]
    if _has_contact(spec, displacement):
        what = "contact (0/1 switch)" if displacement == "gated" else "contact strength"
        out.append(Variable(f"contact.{o}", Role.LATENT, 1, unit="1", description=what))
    out += [
        Variable(f"dpos.{o}", Role.LATENT, d, unit="m", description="displacement over the step"),
        Variable(f"pos.{o}", Role.LATENT, d, unit="m", description="position after the step"),
    ]
    if frame == "push":
        out += frame_object_variables(spec, o)
    if spec.object(o).perceived:
        out.append(
            Variable(
                f"meas.{o}", Role.OBSERVED, d, unit="m", description="perceived position (measurement site)"
            )
        )
    return out


def _default_parents(
    spec: EnvSpec, displacement: str = "gated", frame: str = "world"
) -> dict[str, tuple[str, ...]]:
    """The learned sites' parent sets of the module docstring (in the push frame: :mod:`pal.agent.graph_frame`)."""
    vel = ("v_prev",) if spec.velocities is not None else ()
    out: dict[str, tuple[str, ...]] = {"dq": ("act", "q_prev", *vel)}
    if vel:
        out["v"] = ("act", "q_prev", "v_prev")
    if spec.effector is not None:
        out["dee"] = ("q_prev", "dq")
    for o in spec.object_names:
        if frame == "push":
            out.update(frame_learned_parents(spec, o, _has_contact(spec, displacement)))
            continue
        contact = (f"contact.{o}",) if _has_contact(spec, displacement) else ()
        if contact:
            out[f"contact.{o}"] = (f"rel_prev.{o}", f"rel.{o}")
        momentum = (f"vel_prev.{o}",) if spec.object_momentum else ()
        out[f"dpos.{o}"] = (*contact, f"rel_prev.{o}", f"rel.{o}", *momentum)
    return out


def _fixed_parents(spec: EnvSpec, frame: str = "world") -> dict[str, tuple[str, ...]]:
    out: dict[str, tuple[str, ...]] = {"q": ("q_prev", "dq")}
    if spec.effector is not None:
        out["ee"] = ("ee_prev", "dee")
    for o in spec.object_names:
        out[f"rel_prev.{o}"] = ("ee_prev", f"pos_prev.{o}")
        out[f"rel.{o}"] = ("ee", f"pos_prev.{o}")
        out[f"pos.{o}"] = (f"pos_prev.{o}", f"dpos.{o}")
        if spec.object(o).perceived:
            out[f"meas.{o}"] = (f"pos.{o}",)
    if frame == "push":
        out.update(frame_fixed_parents(spec))
    return out


def learned_sites(spec: EnvSpec, displacement: str = "gated") -> tuple[str, ...]:
    """The sites whose mechanisms are learned (Eq. 4.33), in topological order."""
    return tuple(_default_parents(spec, displacement))


def _arm_variables(spec: EnvSpec, bounds: tuple[np.ndarray, np.ndarray]) -> list[Variable]:
    """The action and the arm's variables of the module docstring."""
    j = len(spec.joints)
    low, high = (tuple(float(x) for x in b) for b in bounds)
    variables = [
        Variable(
            "act",
            Role.ACTION,
            len(spec.actions),
            bounds=(low, high),
            description="actions " + ", ".join(spec.actions),
        ),
        Variable(
            "q_prev",
            Role.OBSERVED,
            j,
            unit="rad",
            lag=1,
            lag_of="q",
            description="joint angles before the step",
        ),
    ]
    if spec.velocities is not None:
        variables.append(
            Variable(
                "v_prev",
                Role.OBSERVED,
                j,
                unit="rad/s",
                lag=1,
                lag_of="v",
                description="joint velocities before",
            )
        )
    variables += [
        Variable("dq", Role.LATENT, j, unit="rad", description="joint motion over the step"),
        Variable("q", Role.LATENT, j, unit="rad", description="joint angles after the step"),
    ]
    if spec.velocities is not None:
        variables.append(
            Variable("v", Role.LATENT, j, unit="rad/s", description="joint velocities after the step")
        )
    if spec.effector is not None:
        e = spec.effector.dim
        variables += [
            Variable(
                "ee_prev",
                Role.OBSERVED,
                e,
                unit="m",
                lag=1,
                lag_of="ee",
                description="effector before the step",
            ),
            Variable("dee", Role.LATENT, e, unit="m", description="effector motion over the step"),
            Variable("ee", Role.LATENT, e, unit="m", description="effector after the step"),
        ]
    return variables


def build_graph(
    spec: EnvSpec,
    bounds: tuple[np.ndarray, np.ndarray],
    parents: Mapping[str, Sequence[str]] | None = None,
    *,
    displacement: str = "gated",
    frame: str = "world",
) -> CausalGraph:
    """The graph of the module docstring.

    Args:
        spec: the environment's spec.
        bounds: ``(low (A,), high (A,))`` action bounds (:func:`pal.agent.spec.check_env`).
        parents: optional learned site -> parents, replacing the default parent sets.
        displacement: ``"gated"`` (the default) or ``"smooth"`` (module docstring): ``"gated"``
            gives every object a ``contact.o`` switch.
        frame: ``"world"`` (the default) or ``"push"``: the objects' learned sites read their
            parents in the push frame (:mod:`pal.agent.graph_frame`); needs an effector.

    Raises:
        ValueError: ``parents`` names a site that is not learned, or the edited graph is not
            admissible (a cycle, an edge into an action, see :class:`models.CausalGraph`).
    """
    if frame not in FRAMES:
        raise ValueError(f"frame {frame!r} unknown; expected one of {list(FRAMES)}")
    if frame == "push" and spec.effector is None:
        raise ValueError(
            "frame='push' turns the objects' parents towards the effector; the spec has no effector"
        )
    variables = _arm_variables(spec, bounds) + (point_variables(spec) if frame == "push" else [])
    for o in spec.object_names:
        variables += _object_sites(spec, o, displacement, frame)
    learned = _default_parents(spec, displacement, frame)
    given = dict(parents or {})
    unknown = sorted(set(given) - set(learned))
    if unknown:
        raise ValueError(f"parents names {unknown}, which are not learned sites; learned: {list(learned)}")
    learned.update({k: tuple(v) for k, v in given.items()})
    edges = [(p, c) for c, ps in {**learned, **_fixed_parents(spec, frame)}.items() for p in ps]
    return CausalGraph(variables, edges)


def _sum(dims: Sequence[int], signs: Sequence[float], out: int, sigma: float) -> LinearMechanism:
    """``out = sum_k sign_k P_k x_k``, each parent padded with zeros (or cut) to ``out`` components."""
    blocks = []
    for d, s in zip(dims, signs, strict=True):
        block = torch.zeros(out, d)
        k = min(d, out)
        block[:k, :k] = s * torch.eye(k)
        blocks.append(block)
    return LinearMechanism.from_coefficients(torch.cat(blocks, 1), sigma=sigma)


def _fixed_mechanisms(spec: EnvSpec, graph: CausalGraph, position_sigma: float) -> dict[str, LinearMechanism]:
    dim = lambda n: graph[n].dim  # noqa: E731
    out = {"q": _sum([dim("q_prev"), dim("dq")], [1, 1], dim("q"), FIXED_SIGMA)}
    if spec.effector is not None:
        out["ee"] = _sum([dim("ee_prev"), dim("dee")], [1, 1], dim("ee"), FIXED_SIGMA)
    for o in spec.object_names:
        for rel, ee in ((f"rel_prev.{o}", "ee_prev"), (f"rel.{o}", "ee")):
            out[rel] = _sum([dim(ee), dim(f"pos_prev.{o}")], [1, -1], dim(rel), FIXED_SIGMA)
        out[f"pos.{o}"] = _sum(
            [dim(f"pos_prev.{o}"), dim(f"dpos.{o}")], [1, 1], dim(f"pos.{o}"), position_sigma
        )  # in the push frame replaced by pos_prev + vel (frame_mechanisms)
        if spec.object(o).perceived:
            out[f"meas.{o}"] = _sum([dim(f"pos.{o}")], [1], dim(f"meas.{o}"), 0.01)
    return out


def _learned(graph: CausalGraph, site: str, c: ModelConfig, site_seed: torch.Generator) -> Any:
    """The initial mechanism of one learned site (:func:`build_model`)."""
    in_dim = sum(graph[p].dim for p in graph.parents(site))
    width = (c.arm_hidden or c.hidden) if site in ("dq", "v", "dee") else c.hidden
    out_dim = graph[site].dim
    gated = c.displacement == "gated"
    if gated and site.startswith("contact."):
        return BernoulliMechanism(in_dim, hidden=width, seed=site_seed)

    bounds = c.arm_log_scale_bounds if site in ("dq", "v", "dee") else c.log_scale_bounds

    def make(g: torch.Generator | None) -> Any:
        if c.kind == "hetero":
            return HeteroscedasticMechanism(
                in_dim, out_dim, hidden=width, log_scale_bounds=bounds, learn_bounds=False, seed=g
            )
        return MLPMechanism(in_dim, out_dim, hidden=width, seed=g)

    mech = make(site_seed) if c.members == 1 else EnsembleMechanism.replicate(make, c.members, site_seed)
    switch = "contact." + site.removeprefix("dpos.")
    if gated and site.startswith("dpos.") and switch in graph.parents(site):
        return GatedMechanism(switch, mech, floor=c.position_sigma)
    return mech


def build_model(
    spec: EnvSpec,
    graph: CausalGraph,
    config: ModelConfig | None = None,
    *,
    mechanisms: Mapping[str, Any] | None = None,
    seed: int = 0,
) -> WorldModel:
    """A :class:`models.WorldModel` over ``graph``: the fixed relations, and learned mechanisms.

    Args:
        spec: the environment's spec.
        graph: from :func:`build_graph` (with the same ``displacement`` as ``config``).
        config: ``kind`` (``"mlp"``, or ``"hetero"``: ``X ~ Normal(f(pa), sigma(pa))``), ensemble
            size ``members`` per learned site, MLP widths ``hidden`` of the object sites and
            ``arm_hidden`` of the arm sites (``dq``, ``v``, ``dee``), the fixed log-scale bounds
            of heteroscedastic sites ``log_scale_bounds`` and ``arm_log_scale_bounds`` (not
            learned), ``position_sigma``, the
            residual sd of ``pos = pos_prev + dpos`` (m), and ``displacement``: with
            ``"gated"`` ``contact.o`` is a :class:`models.BernoulliMechanism` and ``dpos.o`` a
            :class:`models.GatedMechanism` with floor ``position_sigma`` (module docstring).
        mechanisms: optional learned site -> given :class:`models.Mechanism` (e.g. a known law).
        seed: seeds every learned mechanism's initial weights (one stream per site).
    """
    c = config or ModelConfig()
    generator = torch.Generator().manual_seed(seed)
    mechs: dict[str, Any] = dict(_fixed_mechanisms(spec, graph, c.position_sigma))
    if any(n.startswith("local.") for n in graph.names):
        mechs.update(frame_mechanisms(spec, graph, FIXED_SIGMA, c.position_sigma))
        missing = [n for n in POINT_SITES if n in graph and n not in (mechanisms or {})]
        if missing:
            raise ValueError(
                f"sites {missing} are the body's points from its MJCF; give their mechanisms "
                "(pal.agent.kinematics.point_mechanisms)"
            )
    for site in learned_sites(spec, c.displacement):
        if site not in graph:
            continue
        site_seed = torch.Generator().manual_seed(int(torch.randint(0, 2**62, (1,), generator=generator)))
        mechs[site] = _learned(graph, site, c, site_seed)
    mechs.update(mechanisms or {})
    return WorldModel(graph, mechs, seed=seed)


def restrict(model: WorldModel, objects: Sequence[str]) -> WorldModel:
    """The model without the sites of the other objects, a warm-started copy (objects do not act on each other here).

    Raises:
        ValueError: an object that is not in the model.
    """
    g = model.graph
    slots = {n.split(".", 1)[1] for n in g.names if n.startswith("pos.")}
    unknown = sorted(set(objects) - slots)
    if unknown:
        raise ValueError(f"objects {unknown} are not in the model; it has {sorted(slots)}")
    names = [n for n in g.names if "." not in n or n.split(".", 1)[1] in set(objects)]
    return model.with_graph(
        CausalGraph([g[n] for n in names], [(p, c) for p, c in g.edges if p in names and c in names])
    )


def blanket(model: WorldModel, objects: Sequence[str], *, observed_contact: bool = True) -> WorldModel:
    """The object sites of ``objects`` given the effector relations: a warm-started copy for state inference.

    ``rel_prev.o``, ``rel.o`` (and ``contact.o``, ``vel_prev.o``; in the push frame ``prel_prev.o``,
    ``prel.o`` and ``local.o``) become observed roots: with the effector sensed they are known, and
    they d-separate the arm sites from the object sites, so
    the posterior over ``dpos.o`` and ``pos.o`` is that of the full program at a fraction of its sites.
    With ``observed_contact=False`` (a gated switch without touch sensing) ``contact.o`` stays a
    latent site of ``rel_prev.o``, ``rel.o``, enumerated by the inference.
    """
    g = model.graph
    keep_prefix = ("pos_prev.", "vel_prev.", "rel_prev.", "rel.", "contact.", "dpos.", "pos.", "meas.")
    keep_prefix += ("prel_prev.", "prel.", "local.")  # the push frame's (vel.o: a leaf here, left out)
    names = [n for n in g.names if n.startswith(keep_prefix) and n.split(".", 1)[1] in set(objects)]
    observed = ("rel_prev.", "rel.", "prel_prev.", "prel.", "local.") + (
        ("contact.",) if observed_contact else ()
    )
    roots = {n for n in names if n.startswith(observed)}
    variables = [replace(g[n], role=Role.OBSERVED) if n in roots else g[n] for n in names]
    edges = [(p, c) for p, c in g.edges if p in names and c in names and c not in roots]
    return model.with_graph(CausalGraph(variables, edges))


def discover_parents(
    spec: EnvSpec, graph: CausalGraph, data: Mapping[str, np.ndarray], *, seed: int = 0, **kwargs: Any
) -> dict[str, tuple[str, ...]]:
    """Learn the parent sets of the learned sites with :func:`inference.discover`.

    The fixed relations are known; the candidates of each learned site are the variables that
    may cause it in time: tier 1 the actions and the state before the step, tier 2 the joints'
    motion ``dq, v``, tier 3 what follows from the new angles ``dee, q, ee`` (so the joints'
    dynamics never take the effector's motion or the new angles as parents), tier 4 each
    object's relations, tier 5 the object sites.

    Args:
        spec: the environment's spec.
        graph: from :func:`build_graph` (its learned edges are ignored).
        data: name -> ``(N, dim)`` realized values of every variable of ``graph`` except the
            measurement sites.
        seed: seeds the search.
        **kwargs: passed to :func:`inference.discover`.

    Returns:
        learned site -> parents, for :func:`build_graph`.
    """
    names = [n for n in graph.names if not n.startswith("meas.")]
    fixed = _fixed_parents(spec)
    roots = [n for n in names if graph[n].role is not Role.LATENT]
    motion = [n for n in ("dq", "v") if n in names]  # the joints' dynamics over the step
    kinematics = [n for n in ("dee", "q", "ee") if n in names]  # what follows from the new joint angles
    rel = [n for n in names if n.startswith(("rel_prev.", "rel."))]
    done = roots + motion + kinematics + rel
    tiers = [roots, motion, kinematics, rel, [n for n in names if n not in done]]
    required = [(p, c) for c, ps in fixed.items() if c in names for p in ps]
    forbidden = [(p, c) for c in fixed if c in names for p in names if p not in fixed[c] and p != c]
    result = discover(
        [graph[n] for n in names],
        {n: data[n] for n in names},
        tiers=tiers,
        required=required,
        forbidden=forbidden,
        seed=seed,
        **kwargs,
    )
    learned = learned_sites(spec)
    return {c: tuple(p for p in result.graph.parents(c)) for c in learned if c in result.graph}
