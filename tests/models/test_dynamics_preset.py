"""The ``dynamics`` joint-chain graph: dq_prev -> dq, carried forward by rollout (Alg. 4.1)."""

from __future__ import annotations

import pytest
import torch

from models import LinearMechanism, WorldModel
from models.presets import GRAPH_VARIANTS, finger_graph, joint_chain_graph
from models.variables import Role


def test_dynamics_adds_an_observed_lag1_displacement():
    g = finger_graph("dynamics")
    assert GRAPH_VARIANTS == ("thesis", "state", "dynamics")
    var = g["dq_prev.finger"]
    assert var.role is Role.OBSERVED and var.lag == 1 and var.lag_of == "dq.finger" and var.unit == "rad"
    assert set(g.parents("dq.finger")) == {"act.finger", "q_prev.finger", "dq_prev.finger"}
    assert set(g.parents("q.finger")) == set(finger_graph("state").parents("q.finger"))
    two = joint_chain_graph(["a", "b"], {"a": (-1, 1), "b": (-1, 1)}, variant="dynamics")
    assert "dq_prev.a" in two.parents("dq.a") and "dq_prev.a" not in two.parents("dq.b")


def test_rollout_feeds_each_displacement_into_the_next_step():
    # dq = 0.5 a - 0.1 q_prev + 0.8 dq_prev,  q = q_prev + dq  (no noise: expected residuals)
    g = finger_graph("dynamics")
    order = list(g.parents("dq.finger"))
    w = {"act.finger": 0.5, "q_prev.finger": -0.1, "dq_prev.finger": 0.8}
    model = WorldModel(
        g,
        {
            "dq.finger": LinearMechanism.from_coefficients([[w[p] for p in order]]),
            "q.finger": LinearMechanism.from_coefficients(
                [[1.0 if p in ("dq.finger", "q_prev.finger") else 0.0 for p in g.parents("q.finger")]]
            ),
        },
    )
    actions = torch.tensor([[[0.2], [-0.4], [0.1]]])
    traj = model.rollout(
        {"q_prev.finger": torch.tensor([[-1.0]]), "dq_prev.finger": torch.tensor([[0.3]])},
        {"act.finger": actions},
    )
    q, dq_prev = -1.0, 0.3
    for t, a in enumerate((0.2, -0.4, 0.1)):
        dq = 0.5 * a - 0.1 * q + 0.8 * dq_prev
        assert traj["dq.finger"][0, t, 0].item() == pytest.approx(dq, abs=1e-6)
        q, dq_prev = q + dq, dq
        assert traj["q.finger"][0, t, 0].item() == pytest.approx(q, abs=1e-6)


def test_the_velocity_variant_carries_the_joint_velocity_forward():
    """q_prev, v_prev, act -> dq, v; rollout feeds v into v_prev (a Markov state on torque-driven joints)."""
    g = finger_graph("velocity")
    assert g["v_prev.finger"].lag_of == "v.finger" and g["v_prev.finger"].unit == "rad/s"
    assert (
        set(g.parents("dq.finger"))
        == set(g.parents("v.finger"))
        == {"act.finger", "q_prev.finger", "v_prev.finger"}
    )
    dt = 0.05
    lin = lambda w: LinearMechanism.from_coefficients([w])  # noqa: E731
    pa = list(g.parents("dq.finger"))
    coef = {"act.finger": 2.0, "q_prev.finger": 0.0, "v_prev.finger": 0.9}
    model = WorldModel(
        g,
        {
            "v.finger": lin([coef[p] for p in pa]),
            "dq.finger": lin([dt * coef[p] for p in pa]),
            "q.finger": lin(
                [1.0 if p in ("dq.finger", "q_prev.finger") else 0.0 for p in g.parents("q.finger")]
            ),
        },
    )
    traj = model.rollout(
        {"q_prev.finger": torch.tensor([[0.0]]), "v_prev.finger": torch.tensor([[1.0]])},
        {"act.finger": torch.tensor([[[0.3], [-0.5]]])},
    )
    v, q = 1.0, 0.0
    for t, a in enumerate((0.3, -0.5)):
        v = 2.0 * a + 0.9 * v
        q = q + dt * v
        assert traj["v.finger"][0, t, 0].item() == pytest.approx(v, abs=1e-6)
        assert traj["q.finger"][0, t, 0].item() == pytest.approx(q, abs=1e-6)
    with pytest.raises(ValueError, match="graph variant 'speed' unknown"):
        finger_graph("speed")
