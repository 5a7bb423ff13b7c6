import numpy as np
import pytest
import torch

from inference import infer_action
from models import CausalGraph, FunctionMechanism, Variable, WorldModel, finger_graph


@pytest.fixture
def plant():
    """q = q_prev + tanh(2 a), a in [-1, 1]: invertible in a for any q_prev."""
    g = CausalGraph(
        [
            Variable("a", "action", bounds=(-1.0, 1.0)),
            Variable("q_prev", "observed", lag=1, lag_of="q"),
            Variable("q", "latent"),
        ],
        [("a", "q"), ("q_prev", "q")],
    )
    mech = FunctionMechanism(lambda z: z[..., 1:2] + torch.tanh(2 * z[..., 0:1]), 2, 1, sigma=0.1)
    return WorldModel(g, {"q": mech})


def reachable_targets(n, seed):
    g = torch.Generator().manual_seed(seed)
    q_prev = torch.randn(n, 1, generator=g)
    a_true = torch.rand(n, 1, generator=g) * 1.6 - 0.8
    return q_prev, q_prev + torch.tanh(2 * a_true), a_true


def test_reaches_95_percent_of_128_targets(plant):
    q_prev, target, a_true = reachable_targets(128, 0)
    r = infer_action(plant, {"q_prev": q_prev}, {"q": target}, steps=200, lr=0.05)
    err = (r.predicted["q"] - target).abs()
    assert float((err < 0.05).float().mean()) >= 0.95
    assert r.actions["a"].shape == (128, 1)
    assert len(r.loss) == 200 and r.loss[-1] < r.loss[0]
    assert r.final_loss.shape == (128,)
    torch.testing.assert_close(r.actions["a"], a_true, atol=0.05, rtol=0)


def test_actions_stay_within_bounds_for_unreachable_targets(plant):
    q_prev = torch.zeros(4, 1)
    r = infer_action(
        plant, {"q_prev": q_prev}, {"q": torch.tensor([[5.0], [-5.0], [5.0], [-5.0]])}, steps=100, lr=0.2
    )
    torch.testing.assert_close(r.actions["a"].ravel(), torch.tensor([1.0, -1.0, 1.0, -1.0]))


def test_units_are_independent(plant):
    q_prev, target, _ = reachable_targets(8, 1)
    both = infer_action(plant, {"q_prev": q_prev}, {"q": target})
    first = infer_action(plant, {"q_prev": q_prev[:1]}, {"q": target[:1]})
    torch.testing.assert_close(both.actions["a"][:1], first.actions["a"])


def test_inits_and_custom_preference(plant):
    q_prev, target, _ = reachable_targets(16, 2)
    r = infer_action(plant, {"q_prev": q_prev}, {"q": target}, init="random", seed=3)
    r2 = infer_action(plant, {"q_prev": q_prev}, {"q": target}, init="random", seed=3)
    torch.testing.assert_close(r.actions["a"], r2.actions["a"])
    r3 = infer_action(
        plant, {"q_prev": q_prev}, {"q": target}, init={"a": torch.zeros(16, 1)}, steps=1, lr=1e-9
    )
    assert torch.all(r3.actions["a"].abs() < 1e-6)

    def prefer_high(pred):
        return pred["q"][:, 0]

    r4 = infer_action(plant, {"q_prev": q_prev}, log_preference=prefer_high, steps=100, lr=0.1)
    assert torch.all(r4.actions["a"] == 1.0)


def test_finger_preset_runs_batched():
    m = WorldModel(finger_graph("state"))
    r = infer_action(m, {"q_prev.finger": torch.zeros(5, 1)}, {"q.finger": torch.zeros(5, 1)}, steps=3)
    assert set(r.actions) == {"act.finger"}
    lo, hi = -1.0, 0.33
    assert torch.all((r.actions["act.finger"] >= lo) & (r.actions["act.finger"] <= hi))


def test_model_parameters_are_left_untouched(plant):
    m = WorldModel(finger_graph("thesis"))
    before = {k: v.clone() for k, v in m.state_dict().items()}
    infer_action(m, {"q_prev.finger": torch.zeros(3, 1)}, {"q.finger": torch.ones(3, 1)}, steps=10)
    for k, v in m.state_dict().items():
        assert torch.equal(v, before[k]), k
    assert all(p.requires_grad for p in m.parameters())


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"targets": {"w": torch.zeros(2, 1)}}, "unknown variable in targets 'w'"),
        ({"targets": {"q": torch.zeros(3, 1)}}, "has 3 rows, expected 2"),
        ({"targets": {"q": torch.zeros(2, 2)}}, "expected \\(N, 1\\)"),
        ({"targets": {"q": torch.full((2, 1), np.nan)}}, "NaN or inf"),
        ({"targets": {"a": torch.zeros(2, 1)}}, "target 'a' is an optimised action"),
        ({"targets": None}, "give targets or a log_preference"),
        ({"actions": ["q"]}, "only actions can be optimised"),
        ({"init": "zero"}, "init 'zero' unknown"),
        ({"init": {"a": torch.full((2, 1), 3.0)}}, "outside the bounds"),
        ({"steps": 0}, "steps must be a positive int"),
    ],
)
def test_bad_input(plant, kwargs, match):
    args = {"targets": {"q": torch.zeros(2, 1)}, **kwargs}
    with pytest.raises(ValueError, match=match):
        infer_action(plant, {"q_prev": torch.zeros(2, 1)}, **args)
