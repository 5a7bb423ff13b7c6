"""Contextualisation: sensitivities (Eq. 6.5-6.7), active subgraphs, action inference on them."""

from __future__ import annotations

import pytest
import torch

from inference import infer_action
from inference.context import (
    active_subgraph,
    context_sensitivity,
    local_sensitivity,
    subgraph_model,
    target_relevance,
)
from models import WorldModel, joint_chain_graph


def test_linear_chain_sensitivities_are_the_coefficients(chain):
    vals = chain.sample(64, torch.Generator().manual_seed(0))
    local = local_sensitivity(chain, vals)
    torch.testing.assert_close(local["x", "y"], torch.full((64,), 2.0))
    torch.testing.assert_close(local["y", "z"], torch.full((64,), 1.5))
    raw = context_sensitivity(chain, vals, standardise=False)
    assert raw == pytest.approx({("x", "y"): 2.0, ("y", "z"): 1.5})
    rel = target_relevance(chain, {"x": vals["x"]}, ["z"])
    torch.testing.assert_close(rel["x"], torch.full((64,), 3.0))  # |dz/dx| = |2 * -1.5|
    torch.testing.assert_close(rel["y"], torch.full((64,), 1.5))
    torch.testing.assert_close(rel["z"], torch.full((64,), 1.0))


def test_local_sensitivity_matches_finite_differences():
    torch.manual_seed(0)
    model = WorldModel(joint_chain_graph(["j"], {"j": (-1.0, 1.0)}, "state"), hidden=(8,))
    vals = model.sample(5, torch.Generator().manual_seed(1))
    local = local_sensitivity(model, vals)
    h = 1e-3
    up = dict(vals, **{"q_prev.j": vals["q_prev.j"] + h})
    dn = dict(vals, **{"q_prev.j": vals["q_prev.j"] - h})
    fd = (model.loc("dq.j", up) - model.loc("dq.j", dn)).abs()[:, 0] / (2 * h)
    torch.testing.assert_close(local["q_prev.j", "dq.j"], fd, atol=1e-3, rtol=1e-2)


def many_joints(k: int) -> WorldModel:
    joints = [f"j{i}" for i in range(k)]
    torch.manual_seed(0)
    return WorldModel(joint_chain_graph(joints, dict.fromkeys(joints, (-1.0, 1.0)), "state"), hidden=(16,))


def test_active_subgraph_keeps_the_target_joint_only_and_gives_the_same_actions():
    model = many_joints(12)
    samples = model.sample(256, torch.Generator().manual_seed(0))
    sub = active_subgraph(model, samples, ["q.j3"])
    assert set(sub.graph.names) == {"act.j3", "q_prev.j3", "dq.j3", "q.j3"}
    assert len(sub.dropped) == 44 and not sub.clamped
    small = subgraph_model(model, sub)
    assert small.mechanism("dq.j3") is model.mechanism("dq.j3")
    state_full = {k: v[:32] for k, v in samples.items() if k.startswith("q_prev.") or k.startswith("act.")}
    state_full = {k: v for k, v in state_full.items() if k != "act.j3"}
    target = {"q.j3": samples["q.j3"][32:64]}
    full = infer_action(model, state_full, target, actions=["act.j3"], num_steps=60)
    part = infer_action(small, {"q_prev.j3": state_full["q_prev.j3"]}, target, num_steps=60)
    torch.testing.assert_close(part.actions["act.j3"], full.actions["act.j3"], atol=1e-5, rtol=0)
    torch.testing.assert_close(part.predicted["q.j3"], full.predicted["q.j3"], atol=1e-5, rtol=0)


def test_weak_edges_are_pruned_and_their_parents_clamped():
    model = many_joints(1)
    with torch.no_grad():  # make q_prev.j0 -> dq.j0 negligible: zero its first-layer column
        model.mechanism("dq.j0").net[0].weight[:, 1] = 0.0
    samples = model.sample(128, torch.Generator().manual_seed(0))
    sub = active_subgraph(model, samples, ["dq.j0"], threshold=1e-3)
    assert sub.graph.edges == (("act.j0", "dq.j0"),)
    assert set(sub.clamped["dq.j0"]) == {"q_prev.j0"}
    small = subgraph_model(model, sub)
    pred = small.predict({"act.j0": samples["act.j0"]})["dq.j0"]
    full = model.predict({"act.j0": samples["act.j0"], "q_prev.j0": samples["q_prev.j0"]})["dq.j0"]
    torch.testing.assert_close(pred, full, atol=1e-5, rtol=0)


def test_context_inputs_are_checked(chain):
    with pytest.raises(ValueError, match="missing \\['z'\\]"):
        local_sensitivity(chain, {"x": torch.zeros(2, 1), "y": torch.zeros(2, 1)})
    with pytest.raises(ValueError, match="unknown target 'w'"):
        target_relevance(chain, {"x": torch.zeros(2, 1)}, ["w"])
    with pytest.raises(ValueError, match="targets is empty"):
        active_subgraph(chain, chain.sample(4), [])


def test_a_kept_lag_one_root_keeps_its_partner():
    """ee <- ee_prev (lag 1 of ee) and dee <- q_prev (lag 1 of q): targeting ee keeps q, so rollouts carry the state."""
    from models import CausalGraph, LinearMechanism, Variable

    g = CausalGraph(
        [
            Variable("act", "action", 1, bounds=(-1, 1)),
            Variable("q_prev", "observed", 1, lag=1, lag_of="q"),
            Variable("q", "latent", 1),
            Variable("ee_prev", "observed", 1, lag=1, lag_of="ee"),
            Variable("ee", "latent", 1),
        ],
        [("act", "q"), ("q_prev", "q"), ("q_prev", "ee"), ("ee_prev", "ee")],
    )
    lin = lambda *w: LinearMechanism.from_coefficients([list(w)], sigma=1e-3)  # noqa: E731
    model = WorldModel(g, {"q": lin(1.0, 1.0), "ee": lin(0.5, 1.0)})
    sub = active_subgraph(model, model.sample(64, torch.Generator().manual_seed(0)), ["ee"])
    assert set(sub.graph.names) == {"act", "q_prev", "q", "ee_prev", "ee"}
    assert sub.graph["q_prev"].lag_of == "q" and sub.dropped == ()
