"""Editing the graph of a live world model: warm starts and evidence-aware refits."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from inference import FitSchedule, fit
from inference.rewire import evidence_groups, rewire
from models import CausalGraph, FunctionMechanism, Role, Variable, WorldModel, finger_graph


def fitted_thesis_model(rng: np.random.Generator) -> tuple[WorldModel, dict[str, np.ndarray]]:
    n = 400
    a = rng.uniform(-1, 0.33, (n, 1)).astype(np.float32)
    q_prev = rng.uniform(-2.5, 0.3, (n, 1)).astype(np.float32)
    dq = (0.8 * (np.tanh(3 * a) - q_prev) + 0.05 * rng.normal(size=(n, 1))).astype(np.float32)
    data = {"act.finger": a, "q_prev.finger": q_prev, "dq.finger": dq, "q.finger": q_prev + dq}
    torch.manual_seed(0)
    model = WorldModel(finger_graph("thesis"), hidden=(8,))
    fit(model, data, schedule=FitSchedule(epochs=5, batch_size=128), seed=0)
    return model, data


def test_with_graph_keeps_unchanged_and_preserves_function_when_adding_a_parent(rng):
    model, data = fitted_thesis_model(rng)
    state = model.with_graph(finger_graph("state"))
    assert state.provenance["warm_start"] == {"dq.finger": "rewired", "q.finger": "kept"}
    inputs = {k: torch.as_tensor(data[k]) for k in ("act.finger", "q_prev.finger")}
    before, after = model.predict(inputs), state.predict(inputs)
    for k in ("dq.finger", "q.finger"):
        torch.testing.assert_close(after[k], before[k], atol=1e-6, rtol=0)
    torch.testing.assert_close(state.sigma("dq.finger"), model.sigma("dq.finger"))
    # the old model is untouched and the copies are independent
    with torch.no_grad():
        state.mechanism("q.finger").log_sigma.add_(1.0)
    assert not torch.equal(state.sigma("q.finger"), model.sigma("q.finger"))


def test_with_graph_removing_a_parent_keeps_the_other_columns(rng):
    model, _ = fitted_thesis_model(rng)
    g = model.graph.with_edges(remove=[("q_prev.finger", "q.finger")])
    smaller = model.with_graph(g)
    old = model.mechanism("q.finger").net[0].weight
    new = smaller.mechanism("q.finger").net[0].weight
    assert new.shape == (old.shape[0], 1)
    assert model.graph.parents("q.finger") == ("q_prev.finger", "dq.finger")
    torch.testing.assert_close(new[:, 0], old[:, 1])  # the column of dq survives


def test_with_graph_rejects_dim_changes_and_handles_function_mechanisms():
    g = CausalGraph([Variable("x", Role.OBSERVED), Variable("y", Role.LATENT)], [("x", "y")])
    model = WorldModel(g, {"y": FunctionMechanism(lambda z: 2 * z, 1)})
    g2 = CausalGraph(
        [Variable("x", Role.OBSERVED), Variable("w", Role.OBSERVED), Variable("y", Role.LATENT)],
        [("x", "y"), ("w", "y")],
    )
    assert model.with_graph(g2).provenance["warm_start"] == {"y": "new"}
    assert model.with_graph(g).provenance["warm_start"] == {"y": "kept"}
    with pytest.raises(ValueError, match="'y' has dim 2 in the new graph, expected 1"):
        model.with_graph(CausalGraph([Variable("x", Role.OBSERVED), Variable("y", Role.LATENT, dim=2)]))


def test_rewire_refits_only_changed_mechanisms_on_their_evidence_rows(rng):
    model, data = fitted_thesis_model(rng)
    kept_before = {k: v.clone() for k, v in model.mechanism("q.finger").state_dict().items()}
    cut = np.zeros(len(data["dq.finger"]), bool)
    cut[:100] = True
    res = rewire(
        model,
        finger_graph("state"),
        data,
        intervened={"dq.finger": cut},
        schedule=FitSchedule(epochs=3, batch_size=128),
        seed=0,
    )
    assert res.warm_start == {"dq.finger": "rewired", "q.finger": "kept"}
    # 400 rows, 100 of them intervened on dq: 300 evidence rows, 10 % held out for sigma
    assert len(res.fits) == 1 and res.fits[0].trained == ("dq.finger",) and res.fits[0].n_train == 270
    for k, v in res.model.mechanism("q.finger").state_dict().items():
        torch.testing.assert_close(v, kept_before[k])
    with pytest.raises(ValueError, match="refit 'some' unknown"):
        rewire(model, finger_graph("state"), data, refit="some")
    with pytest.raises(ValueError, match="data is needed to refit"):
        rewire(model, finger_graph("state"))


def test_evidence_groups():
    groups = evidence_groups(["a", "b", "c"], 4, {"b": np.array([True, False, False, False])})
    assert [g[0] for g in groups] == [["a", "c"], ["b"]]
    assert groups[1][1].tolist() == [False, True, True, True]
