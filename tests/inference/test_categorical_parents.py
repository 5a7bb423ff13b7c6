"""Categorical parents with K > 2 in contextualisation, rewiring and meta-learning."""

from __future__ import annotations

import pytest
import torch

from inference import FitSchedule, active_subgraph, revise, rewire, subgraph_model
from inference.context import ActiveSubgraph, local_sensitivity, target_relevance
from models import CausalGraph, LinearMechanism, Variable, WorldModel


def model_k3():
    """C (3 categories) -> Y <- X, Y -> Z; Y = (0, 1.5, -1.5)[C] + X + 0.3 U, Z = Y + 0.3 U."""
    g = CausalGraph(
        [
            Variable("c", "observed"),
            Variable("x", "observed"),
            Variable("y", "observed"),
            Variable("z", "observed"),
        ],
        [("c", "y"), ("x", "y"), ("y", "z")],
    )
    mechs = {
        "y": LinearMechanism.from_coefficients([[0.0, 1.5, -1.5, 1.0]], sigma=0.3),
        "z": LinearMechanism.from_coefficients([[1.0]], sigma=0.3),
    }
    m = WorldModel(g, mechs, discrete={"c": 3})
    m.set_root_probs("c", [0.3, 0.3, 0.4])
    return m


def test_sensitivities_refuse_categorical_parents_by_name():
    m = model_k3()
    s = m.sample(50, torch.Generator().manual_seed(0))
    for call in (
        lambda: local_sensitivity(m, s),
        lambda: active_subgraph(m, s, ["z"]),
        lambda: target_relevance(m, s, ["z"]),
    ):
        with pytest.raises(ValueError, match=r"categorical parents \{'c': 3\}.*one-hot"):
            call()


def test_subgraph_model_keeps_categorical_sites_and_refuses_clamping_them():
    m = model_k3()
    g = m.graph
    sub = ActiveSubgraph(
        CausalGraph([g[n] for n in g.names], [("c", "y"), ("y", "z")]), {}, {"y": {"x": torch.zeros(1)}}, ()
    )
    small = subgraph_model(m, sub)
    assert small.discrete == {"c": 3}
    out = small.predict({"c": torch.tensor([[0.0], [1.0], [2.0]]), "x": torch.zeros(3, 1)})
    torch.testing.assert_close(out["y"], torch.tensor([[0.0], [1.5], [-1.5]]))
    clamp_c = ActiveSubgraph(
        CausalGraph([g[n] for n in g.names], [("x", "y"), ("y", "z")]), {}, {"y": {"c": torch.ones(1)}}, ()
    )
    with pytest.raises(ValueError, match=r"clamping pruned parents.*\{'c': 3\}"):
        subgraph_model(m, clamp_c)


def test_rewire_adds_a_categorical_parent_and_refits():
    m = model_k3()
    data = m.sample(400, torch.Generator().manual_seed(0))
    r = rewire(
        m, m.graph.with_edges(add=[("c", "z")]), data, seed=0, schedule=FitSchedule(epochs=30, batch_size=64)
    )
    assert r.warm_start == {"y": "kept", "z": "new"}
    assert r.model.discrete == {"c": 3} and r.model.mechanism("z").in_dim == 4  # one-hot c + y
    # Z does not depend on C given Y: the refit keeps z ~ y
    with torch.no_grad():
        d = r.model.predict({"c": torch.tensor([[2.0]]), "x": torch.zeros(1, 1), "y": torch.ones(1, 1)})["z"]
    assert float(d) == pytest.approx(1.0, abs=0.15)


def test_revise_adds_a_categorical_parent_when_it_helps():
    g = CausalGraph(
        [Variable("c", "observed"), Variable("x", "observed"), Variable("y", "observed")], [("x", "y")]
    )
    truth = WorldModel(
        g.with_edges(add=[("c", "y")]),
        {"y": LinearMechanism.from_coefficients([[0.0, 2.0, -2.0, 1.0]], sigma=0.3)},
        discrete={"c": 3},
    )
    data = truth.sample(600, torch.Generator().manual_seed(1))
    start = WorldModel(g, seed=0, kind="linear", discrete={"c": 3})
    revised, log = revise(start, data, ["y"], kinds=["add_parent"], seed=0)
    assert revised.graph.parents("y") == ("c", "x") and revised.discrete == {"c": 3}
    assert [r.accepted for r in log] == [True] and log[0].gain > 100
    assert revised.mechanism("y").in_dim == 4  # c enters one-hot, not as a number
    with pytest.raises(ValueError, match="discrete site"):
        revise(
            WorldModel(truth.graph, seed=0, discrete={"c": 3, "y": 2}),
            data | {"y": (data["y"] > 0).float()},
            ["y"],
        )
