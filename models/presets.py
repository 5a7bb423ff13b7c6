"""Graphs used by the experiments.

``finger_graph("thesis")`` is thesis Fig. 5.5 for one joint j:

    act.j -> dq.j -> q.j <- q_prev.j

with V_act = {act.j}, V_obs = {q_prev.j}, V_lat = {dq.j, q.j} (Eq. 5.2). The ``"state"``
variant adds q_prev.j -> dq.j: the spring torque, the joint limits and gravity all depend
on the joint angle, so the displacement has the previous angle as a real parent. The
``"dynamics"`` variant adds the previous step's displacement as an observed lag-1 root,

    dq_prev.j -> dq.j,     dq_prev.j(t) = dq.j(t - 1) = q(t-1) - q(t-2),

because a body that is still moving at t-1 keeps moving: without it the state has no
velocity, and the command and the angle alone cannot tell where the joint goes.
``rollout`` carries it forward (``lag_of = dq.j``, Alg. 4.1). On a torque-driven joint that
displacement is only a proxy of the velocity at the step's start. The ``"velocity"`` variant
makes the state Markov with the simulator's joint velocity (MuJoCo's ``qvel``):

    act.j, q_prev.j, v_prev.j -> dq.j,     act.j, q_prev.j, v_prev.j -> v.j,

``v_prev.j`` an observed lag-1 root (``lag_of = v.j``), so ``rollout`` carries ``v`` forward.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from models.checks import check_float, check_int, check_mapping, check_names, check_seed, describe
from models.graph import CausalGraph
from models.variables import Role, Variable

__all__ = [
    "ALL_VARIANTS",
    "FINGER_ACTION_RANGE",
    "FINGER_Q_RANGE",
    "GRAPH_VARIANTS",
    "chain_graph",
    "finger_graph",
    "joint_chain_graph",
    "pushing_graph",
    "random_graph",
]

#: The variants fitted by default (they need only joint angles).
GRAPH_VARIANTS = ("thesis", "state", "dynamics")
#: Every variant: the defaults and ``"velocity"`` (needs the joint velocity columns).
ALL_VARIANTS = (*GRAPH_VARIANTS, "velocity")

#: Action range X_a of the left finger motor (thesis §5.2.1): ctrl range of the motor.
FINGER_ACTION_RANGE = (-1.0, 0.33)
#: Observed post-action position range X_q reported by the thesis (§5.2.1), rad.
FINGER_Q_RANGE = (-2.754, 0.519)


def joint_chain_graph(
    joints: Sequence[str],
    action_ranges: Mapping[str, tuple[float, float]],
    variant: str = "thesis",
    q_ranges: Mapping[str, tuple[float, float]] | None = None,
) -> CausalGraph:
    """Independent per-joint chains ``act.j -> dq.j -> q.j <- q_prev.j``.

    Args:
        joints: joint names; variables are named ``act.<j>``, ``q_prev.<j>``, ``dq.<j>``, ``q.<j>``
            (and ``dq_prev.<j>`` in the ``"dynamics"`` variant).
        action_ranges: joint -> (low, high) motor command range.
        variant: ``"thesis"`` (Fig. 5.5), ``"state"`` (adds ``q_prev.j -> dq.j``) or
            ``"dynamics"`` (``state`` plus the observed lag-1 root ``dq_prev.j -> dq.j``) or
            ``"velocity"`` (``state`` plus ``v_prev.j -> dq.j`` and the site ``v.j`` of
            ``act.j, q_prev.j, v_prev.j``; rad/s).
        q_ranges: optional joint -> (low, high) angle range, rad, stored as bounds of q and q_prev.
    """
    if not isinstance(variant, str) or variant not in ALL_VARIANTS:
        raise ValueError(f"graph variant {variant!r} unknown; expected one of {ALL_VARIANTS}")
    joints = check_names("joints", joints, allow_empty=False)
    action_ranges = check_mapping("action_ranges", action_ranges)
    missing = [j for j in joints if j not in action_ranges]
    if missing:
        raise ValueError(f"no action range for joints {missing}")
    q_ranges = dict(check_mapping("q_ranges", q_ranges, allow_none=True))
    unknown = sorted(str(j) for j in q_ranges if j not in joints)
    if unknown:
        raise ValueError(f"q_ranges names unknown joints {unknown}; joints: {joints}")
    variables: list[Variable] = []
    edges: list[tuple[str, str]] = []
    for j in joints:
        q_bounds = q_ranges.get(j)
        variables += [
            Variable(f"act.{j}", Role.ACTION, bounds=action_ranges[j], unit="1", description="motor command"),
            Variable(
                f"q_prev.{j}",
                Role.OBSERVED,
                bounds=q_bounds,
                unit="rad",
                lag=1,
                lag_of=f"q.{j}",
                description="joint angle before the action, q(t-1)",
            ),
            Variable(f"dq.{j}", Role.LATENT, unit="rad", description="displacement q(t) - q(t-1)"),
            Variable(
                f"q.{j}",
                Role.LATENT,
                bounds=q_bounds,
                unit="rad",
                description="joint angle after the action, q(t)",
            ),
        ]
        edges += [(f"act.{j}", f"dq.{j}"), (f"dq.{j}", f"q.{j}"), (f"q_prev.{j}", f"q.{j}")]
        if variant in ("state", "dynamics", "velocity"):
            edges.append((f"q_prev.{j}", f"dq.{j}"))
        if variant == "velocity":
            _velocity(j, variables, edges)
        if variant == "dynamics":
            variables.append(
                Variable(
                    f"dq_prev.{j}",
                    Role.OBSERVED,
                    unit="rad",
                    lag=1,
                    lag_of=f"dq.{j}",
                    description="displacement of the previous step, q(t-1) - q(t-2)",
                )
            )
            edges.append((f"dq_prev.{j}", f"dq.{j}"))
    return CausalGraph(variables, edges)


def _velocity(j: str, variables: list[Variable], edges: list[tuple[str, str]]) -> None:
    """Add the ``"velocity"`` variant's ``v_prev.j -> dq.j`` and ``act.j, q_prev.j, v_prev.j -> v.j``."""
    variables += [
        Variable(
            f"v_prev.{j}",
            Role.OBSERVED,
            unit="rad/s",
            lag=1,
            lag_of=f"v.{j}",
            description="joint velocity at the step's start",
        ),
        Variable(f"v.{j}", Role.LATENT, unit="rad/s", description="joint velocity at the step's end"),
    ]
    edges.append((f"v_prev.{j}", f"dq.{j}"))
    edges += [(p, f"v.{j}") for p in (f"act.{j}", f"q_prev.{j}", f"v_prev.{j}")]


def finger_graph(variant: str = "thesis", joint: str = "finger") -> CausalGraph:
    """Thesis Fig. 5.5 for the left finger (``"thesis"``), with q_prev -> dq (``"state"``), or with dq_prev too (``"dynamics"``)."""
    if not isinstance(joint, str):
        raise ValueError(f"joint must be a joint name (str), got {describe(joint)}")
    return joint_chain_graph(
        [joint], {joint: FINGER_ACTION_RANGE}, variant=variant, q_ranges={joint: FINGER_Q_RANGE}
    )


def chain_graph() -> CausalGraph:
    """The three-node chain X -> Y -> Z (all scalar; X observed, Y and Z latent)."""
    return CausalGraph(
        [Variable("x", Role.OBSERVED), Variable("y", Role.LATENT), Variable("z", Role.LATENT)],
        [("x", "y"), ("y", "z")],
    )


def random_graph(d: int, expected_parents: float = 2.0, seed: int = 0, prefix: str = "x") -> CausalGraph:
    """A random DAG over d scalar variables ``x0 .. x{d-1}`` (Erdos-Renyi in a random order).

    Each pair (i < j in a random causal order) is an edge with probability
    ``expected_parents * 2 / (d - 1)`` capped at 1, so a node has ``expected_parents`` parents
    on average. Roots are observed, the rest latent.

    Args:
        d: number of variables, >= 2.
        expected_parents: mean number of parents, > 0.
        seed: seeds the local numpy generator (the global RNG is not touched).
        prefix: name prefix.
    """
    d = check_int("d", d, minimum=2)
    expected_parents = check_float("expected_parents", expected_parents, minimum=0.0, min_open=True)
    seed = check_seed("seed", seed)
    if not isinstance(prefix, str):
        raise ValueError(f"prefix must be a str, got {describe(prefix)}")
    rng = np.random.default_rng(seed)
    order = rng.permutation(d)
    p = min(1.0, 2.0 * expected_parents / (d - 1))
    edges = [
        (f"{prefix}{order[i]}", f"{prefix}{order[j]}")
        for i in range(d)
        for j in range(i + 1, d)
        if rng.random() < p
    ]
    children = {c for _, c in edges}
    variables = [
        Variable(f"{prefix}{k}", Role.LATENT if f"{prefix}{k}" in children else Role.OBSERVED)
        for k in range(d)
    ]
    return CausalGraph(variables, edges)


def pushing_graph(
    joints: Sequence[str],
    action_ranges: Mapping[str, tuple[float, float]],
    objects: Sequence[str] = ("box",),
    *,
    q_ranges: Mapping[str, tuple[float, float]] | None = None,
    object_dim: int = 2,
) -> CausalGraph:
    """The pushing world model: actions move joints, joints move the hand, the hand pushes objects.

    Per joint j (the ``"state"`` chain): ``act.j -> dq.j -> q.j <- q_prev.j``, ``q_prev.j -> dq.j``.
    Hand: ``{q.j} -> hand`` and ``{q_prev.j} -> hand_prev`` (learned kinematics, 3-D, m).
    Per object o (position on the table, ``object_dim``-D, m)::

        hand_prev, hand, pos_prev.o -> contact.o            (contact strength, 1-D)
        contact.o, hand_prev, hand, pos_prev.o -> dpos.o    (displacement over the step)
        pos_prev.o, dpos.o -> pos.o -> meas.o               (meas.o ~ Normal(pos.o, sigma_perception))

    ``meas.o`` is the measurement site through which perceived positions enter the model;
    ``pos.o`` is the true (latent) position. ``pos_prev.o`` is the previous step's estimate.
    """
    object_dim = check_int("object_dim", object_dim, minimum=2, maximum=3)
    objects = check_names("objects", objects, allow_empty=False)
    clash = sorted(set(objects) & {"hand", "hand_prev"})
    if clash:
        raise ValueError(f"object names {clash} clash with the hand variables")
    arm = joint_chain_graph(joints, action_ranges, variant="state", q_ranges=q_ranges)
    variables = [arm[n] for n in arm.names]
    edges = list(arm.edges)
    variables += [
        Variable("hand_prev", Role.LATENT, dim=3, unit="m", lag=1, lag_of="hand", description="hand at t-1"),
        Variable("hand", Role.LATENT, dim=3, unit="m", description="hand position after the action"),
    ]
    edges += [(f"q.{j}", "hand") for j in joints] + [(f"q_prev.{j}", "hand_prev") for j in joints]
    for o in objects:
        variables += [
            Variable(
                f"pos_prev.{o}",
                Role.OBSERVED,
                dim=object_dim,
                unit="m",
                lag=1,
                lag_of=f"pos.{o}",
                description="object position before the action (previous estimate)",
            ),
            Variable(f"contact.{o}", Role.LATENT, unit="1", description="hand-object contact strength"),
            Variable(f"dpos.{o}", Role.LATENT, dim=object_dim, unit="m", description="object displacement"),
            Variable(f"pos.{o}", Role.LATENT, dim=object_dim, unit="m", description="true object position"),
            Variable(
                f"meas.{o}",
                Role.OBSERVED,
                dim=object_dim,
                unit="m",
                description="perceived object position (measurement site)",
            ),
        ]
        context = ("hand_prev", "hand", f"pos_prev.{o}")
        edges += [(c, f"contact.{o}") for c in context]
        edges += [(c, f"dpos.{o}") for c in (f"contact.{o}", *context)]
        edges += [(f"pos_prev.{o}", f"pos.{o}"), (f"dpos.{o}", f"pos.{o}"), (f"pos.{o}", f"meas.{o}")]
    return CausalGraph(variables, edges)
