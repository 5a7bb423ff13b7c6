"""Meta-learning (Eq. 4.50): residual monitor and tested structural revisions."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from inference import FitSchedule, fit
from inference.metalearn import ResidualMonitor, SplitMechanism, revise
from models import CausalGraph, FunctionMechanism, LinearMechanism, Role, Variable, WorldModel, finger_graph


def spring_truth() -> WorldModel:
    """dq = 0.8 (q_eq(a) - q_prev) + 0.05 U: the displacement depends on the previous angle."""

    def displacement(z: torch.Tensor) -> torch.Tensor:
        return 0.8 * (-0.7 + 1.6 * torch.tanh(3 * z[..., 0:1]) - z[..., 1:2])

    truth = WorldModel(
        finger_graph("state"),
        {
            "dq.finger": FunctionMechanism(displacement, 2, 1, sigma=0.05),
            "q.finger": LinearMechanism.from_coefficients([[1.0, 1.0]], sigma=0.01),
        },
    )
    truth.set_root_prior("q_prev.finger", -1.0, 0.8)
    return truth


FIT = {"schedule": FitSchedule(epochs=20, batch_size=200)}


def test_monitor_flags_the_missing_parent_and_revise_adds_it():
    data = spring_truth().sample(1000, torch.Generator().manual_seed(0))
    torch.manual_seed(0)
    model = WorldModel(finger_graph("thesis"), hidden=(16,))
    fit(model, data, seed=0, **FIT)
    monitor = ResidualMonitor(model, window=500, tolerance={"dq.finger": 0.05, "q.finger": 0.05}, patience=2)
    for k in range(2):  # two windows after the fit: the residual stays high
        monitor.update(model, {n: v[500 * k : 500 * (k + 1)] for n, v in data.items()})
    assert monitor.flagged() == ["dq.finger"]  # q = q_prev + dq is fine
    revised, log = revise(model, data, monitor.flagged(), hidden=(16,), fit_kwargs=FIT)
    kinds = {r.kind: r for r in log}
    assert set(kinds) == {"add_parent", "capacity", "split"}
    best = [r for r in log if r.accepted]
    assert len(best) == 1 and best[0].kind == "add_parent" and best[0].detail == "q_prev.finger -> dq.finger"
    assert best[0].gain > 100 and best[0].n_val == 300
    assert ("q_prev.finger", "dq.finger") in revised.graph.edges
    assert revised.provenance["revisions"][0]["kind"] == "add_parent"
    assert model.graph == finger_graph("thesis")  # the input model is unchanged
    monitor2 = ResidualMonitor(revised, window=500, tolerance={"dq.finger": 0.05, "q.finger": 0.05})
    assert monitor2.update(revised, data)["dq.finger"] < 2.0


@pytest.mark.slow
def test_capacity_revision_when_the_mechanism_underfits(rng):
    x = rng.uniform(-2, 2, (800, 1)).astype(np.float32)
    y = (np.sin(3 * x) + 0.05 * rng.normal(size=(800, 1))).astype(np.float32)
    g = CausalGraph([Variable("x", Role.OBSERVED), Variable("y", Role.LATENT)], [("x", "y")])
    model = WorldModel(g, kind="linear")
    fit(model, {"x": x, "y": y}, seed=0, **FIT)
    revised, log = revise(
        model,
        {"x": x, "y": y},
        ["y"],
        kinds=("capacity", "split"),
        hidden=(16,),
        fit_kwargs={"schedule": FitSchedule(epochs=60, batch_size=200)},
    )
    accepted = [r for r in log if r.accepted]
    assert [r.kind for r in accepted] == ["capacity"]
    assert revised.mechanism("y").kind == "mlp"


def test_split_mechanism_switches_on_the_cut():
    low = LinearMechanism.from_coefficients([[1.0]])
    high = LinearMechanism.from_coefficients([[-1.0]])
    split = SplitMechanism(low, high, 0, 0.5)
    out = split(torch.tensor([[0.0], [1.0]]))
    torch.testing.assert_close(out, torch.tensor([[0.0], [-1.0]]))


def test_a_monitor_restored_from_its_state_flags_as_the_original():
    data = spring_truth().sample(400, torch.Generator().manual_seed(0))
    model = WorldModel(finger_graph("thesis"), seed=0)
    monitor = ResidualMonitor(model, window=300, tolerance={"dq.finger": 0.05}, patience=2)
    monitor.update(model, {n: v[:200] for n, v in data.items()})
    state = json.loads(json.dumps(monitor.state()))  # JSON-ready
    copy = ResidualMonitor.from_state(model, state)
    for m in (monitor, copy):
        m.update(model, {n: v[200:] for n, v in data.items()})
    assert copy.levels == monitor.levels and copy.history == monitor.history
    # the graph's order, not a set's (whose order changes with the hash seed of the process)
    assert list(copy.levels) == list(copy.history) == list(model.graph.non_roots)
    assert copy.flagged() == monitor.flagged() and len(copy.history["dq.finger"]) == 300
    other = WorldModel(finger_graph("thesis", joint="thumb"), seed=0)
    with pytest.raises(ValueError, match="monitor state covers"):
        ResidualMonitor.from_state(other, state)


def test_revise_and_monitor_check_inputs():
    model = WorldModel(finger_graph("thesis"))
    with pytest.raises(ValueError, match="window must be a positive int"):
        ResidualMonitor(model, window=0)
    data = spring_truth().sample(50, torch.Generator().manual_seed(0))
    with pytest.raises(ValueError, match="'act.finger' is a root"):
        revise(model, data, ["act.finger"])
    with pytest.raises(ValueError, match="unknown revision kinds \\['grow'\\]"):
        revise(model, data, ["dq.finger"], kinds=("grow",))
