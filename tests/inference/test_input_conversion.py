"""The inference entry points take float64 tensors and numpy arrays (converted to the model's dtype)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from inference import (
    ActionOptions,
    CuriositySampler,
    DiscoveryOptions,
    Ensemble,
    FitSchedule,
    ReplayNoise,
    ResidualMonitor,
    active_subgraph,
    counterfactual,
    discover,
    do,
    fit,
    infer_action,
    infer_state,
    simulate,
)
from models import CausalGraph, LinearMechanism, Role, Variable, WorldModel, finger_graph


def f64(x) -> torch.Tensor:
    return torch.as_tensor(x, dtype=torch.float64)


def finger_data(n: int = 64) -> dict[str, torch.Tensor]:
    """float64 columns, as ``torch.from_numpy`` gives them."""
    rng = np.random.default_rng(0)
    a = rng.uniform(-1.0, 0.33, (n, 1))
    q_prev = rng.uniform(-1.0, 0.0, (n, 1))
    dq = 0.5 * a - 0.2 * q_prev
    return {
        k: torch.from_numpy(v)
        for k, v in {
            "act.finger": a,
            "q_prev.finger": q_prev,
            "dq.finger": dq,
            "q.finger": q_prev + dq,
        }.items()
    }


def test_fit_takes_float64_tensors():
    model = WorldModel(finger_graph("state"), seed=0, hidden=(4,))
    result = fit(model, finger_data(), schedule=FitSchedule(epochs=2, batch_size=16))
    assert result.trained == ("dq.finger", "q.finger")


# few SVI steps on purpose: the test checks dtypes, not the posterior
@pytest.mark.filterwarnings("ignore::inference.PoorPosteriorWarning")
def test_state_and_counterfactual_take_float64(chain):
    post = infer_state(chain, {"z": f64([[-3.0]])}, num_steps=5, num_samples=4)
    assert post.mean["y"].dtype == torch.float32
    factual = {"x": f64([[1.0]]), "y": f64([[2.5]]), "z": f64([[-3.0]])}
    r = counterfactual(chain, factual, [{"x": f64(0.0)}, {"y": np.zeros((1, 1))}])
    assert float(r.mean["z"][0, 0, 0]) == pytest.approx(0.0, abs=1e-5)
    assert float(r.mean["z"][1, 0, 0]) == pytest.approx(0.75, abs=1e-5)


def test_do_and_simulate_take_numpy_float64(chain):
    out = do(chain, {"x": np.full((3, 1), 2.0)})(None, 3)
    assert out["x"].dtype == torch.float32 and torch.all(out["x"] == 2.0)
    sim = simulate(chain, 4, {"x": f64([1.0])}, seed=0)
    assert torch.all(sim["x"] == 1.0)


def test_infer_action_takes_float64():
    model = WorldModel(finger_graph("state"), seed=0, hidden=(4,))
    r = infer_action(
        ReplayNoise({"dq.finger": f64(np.zeros((3, 1)))}, default="expected")(model),
        {"q_prev.finger": f64(np.zeros((3, 1)))},
        {"q.finger": f64(np.full((3, 1), -0.2))},
        options=ActionOptions(init={"act.finger": f64(np.zeros((3, 1)))}),
        num_steps=3,
    )
    assert r.actions["act.finger"].dtype == torch.float32


def test_ensemble_context_and_monitor_take_float64():
    g = CausalGraph([Variable("a", Role.ACTION, bounds=(-1, 1)), Variable("y", Role.LATENT)], [("a", "y")])
    ens = Ensemble([WorldModel(g, {"y": LinearMechanism.from_coefficients([[s]])}) for s in (1.0, 2.0)])
    chosen, _ = ens.choose({}, {"a": f64(np.linspace(-1, 1, 6).reshape(2, 3, 1))}, ["y"])
    assert chosen["a"].dtype == torch.float32
    model = WorldModel(finger_graph("state"), seed=0, hidden=(4,))
    data = finger_data()
    sub = active_subgraph(model, data, ["q.finger"])
    assert "q.finger" in sub.graph
    monitor = ResidualMonitor(model, window=8)
    assert set(monitor.update(model, data)) == {"dq.finger", "q.finger"}


def test_discovery_and_curiosity_take_float32_tensors():
    gen = torch.Generator().manual_seed(0)
    x = torch.randn(40, 1, generator=gen)
    y = torch.tanh(2 * x) + 0.1 * torch.randn(40, 1, generator=gen)
    res = discover(
        [Variable("x", "observed"), Variable("y", "observed")],
        {"x": x, "y": y},
        options=DiscoveryOptions(features=8),
    )
    assert len(res.graph.edges) == 1
    s = CuriositySampler(-3.0, 3.0, bins=6).fit(x)
    assert s.counts_.sum() == 40
