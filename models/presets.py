"""Graphs used by the experiments.

``finger_graph("thesis")`` is thesis Fig. 5.5 for one joint j:

    act.j -> dq.j -> q.j <- q_prev.j

with V_act = {act.j}, V_obs = {q_prev.j}, V_lat = {dq.j, q.j} (Eq. 5.2). The ``"state"``
variant adds q_prev.j -> dq.j: the spring torque, the joint limits and gravity all depend
on the joint angle, so the displacement has the previous angle as a real parent.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from models.graph import CausalGraph
from models.variables import Role, Variable

__all__ = [
    "FINGER_ACTION_RANGE",
    "FINGER_Q_RANGE",
    "GRAPH_VARIANTS",
    "chain_graph",
    "finger_graph",
    "joint_chain_graph",
    "random_graph",
]

GRAPH_VARIANTS = ("thesis", "state")

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
        joints: joint names; variables are named ``act.<j>``, ``q_prev.<j>``, ``dq.<j>``, ``q.<j>``.
        action_ranges: joint -> (low, high) motor command range.
        variant: ``"thesis"`` (Fig. 5.5) or ``"state"`` (adds ``q_prev.j -> dq.j``).
        q_ranges: optional joint -> (low, high) angle range, rad, stored as bounds of q and q_prev.
    """
    if variant not in GRAPH_VARIANTS:
        raise ValueError(f"graph variant {variant!r} unknown; expected one of {GRAPH_VARIANTS}")
    if not joints:
        raise ValueError("joints is empty; expected at least one joint name")
    missing = [j for j in joints if j not in action_ranges]
    if missing:
        raise ValueError(f"no action range for joints {missing}")
    q_ranges = dict(q_ranges or {})
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
        if variant == "state":
            edges.append((f"q_prev.{j}", f"dq.{j}"))
    return CausalGraph(variables, edges)


def finger_graph(variant: str = "thesis", joint: str = "finger") -> CausalGraph:
    """Thesis Fig. 5.5 for the left finger (``variant="thesis"``), or with q_prev -> dq (``"state"``)."""
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
    """
    if d < 2:
        raise ValueError(f"d must be >= 2, got {d}")
    if not expected_parents > 0:
        raise ValueError(f"expected_parents must be > 0, got {expected_parents}")
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
