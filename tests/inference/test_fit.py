import math

import numpy as np
import pytest
import torch

from inference import fit
from models import CausalGraph, Variable, WorldModel, finger_graph


def nonlinear_data(n, seed):
    """Y = sin(2X) + 0.5 X + 0.4 U, X ~ N(0, 1): noise variance 0.16."""
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(n, 1))
    y = np.sin(2 * x) + 0.5 * x + 0.4 * rng.normal(size=(n, 1))
    return {"x": x, "y": y}


def graph():
    return CausalGraph([Variable("x", "observed"), Variable("y", "latent")], [("x", "y")])


@pytest.mark.parametrize("loss", ["mse", "nll"])
def test_mlp_recovers_a_nonlinear_mechanism_and_its_noise(loss):
    torch.manual_seed(0)
    model = WorldModel(graph())
    result = fit(model, nonlinear_data(10000, 0), loss=loss, epochs=40, batch_size=256, lr=0.01, seed=0)
    test = nonlinear_data(5000, 1)
    with torch.no_grad():
        pred = model.mechanism("y")(torch.tensor(test["x"], dtype=torch.float32)).numpy()
    mse = float(((pred - test["y"]) ** 2).mean())
    assert mse <= 1.10 * 0.16, mse
    assert result.sigma["y"][0] == pytest.approx(0.4, rel=0.05)
    assert len(result.train_loss["y"]) == 40
    assert result.train_loss["y"][-1] < result.train_loss["y"][0]
    # the root prior is the data's mean and sd
    loc, scale = model.root_priors.get("x")
    assert float(loc) == pytest.approx(0.0, abs=0.05) and float(scale) == pytest.approx(1.0, abs=0.05)


def test_validation_curves_and_plot():
    model = WorldModel(graph())
    result = fit(model, nonlinear_data(2000, 0), epochs=3, batch_size=500, val_fraction=0.25)
    assert result.n_val == 500 and result.n_train == 1500
    assert len(result.val_loss["y"]) == 3
    assert all(math.isfinite(v) for v in result.val_loss["y"])
    fig = result.plot()
    assert len(fig.axes) == 1


def test_fit_is_seeded():
    a, b = WorldModel(graph()), WorldModel(graph())
    b.load_state_dict(a.state_dict())
    data = nonlinear_data(1000, 0)
    ra = fit(a, data, epochs=2, batch_size=100, seed=5)
    rb = fit(b, data, epochs=2, batch_size=100, seed=5)
    assert ra.train_loss == rb.train_loss


def test_fit_trains_only_what_the_data_supports():
    model = WorldModel(finger_graph("thesis"))
    rng = np.random.default_rng(0)
    data = {"act.finger": rng.uniform(-1, 0.33, (500, 1)), "dq.finger": rng.normal(size=(500, 1))}
    result = fit(model, data, epochs=1)
    assert result.trained == ("dq.finger",)
    with pytest.raises(
        ValueError, match="cannot fit 'q.finger': data has no column for \\['q.finger', 'q_prev.finger'\\]"
    ):
        fit(model, data, variables=["q.finger"], epochs=1)


@pytest.mark.parametrize(
    ("data", "kwargs", "match"),
    [
        ({"x": np.zeros((10, 1)), "w": np.zeros((10, 1))}, {}, "unknown variable in data 'w'"),
        ({"x": np.zeros(10), "y": np.zeros((10, 1))}, {}, "expected \\(N, 1\\)"),
        ({"x": np.zeros((10, 1)), "y": np.full((10, 1), np.nan)}, {}, "NaN or inf"),
        ({"x": np.zeros((10, 1)), "y": np.zeros((9, 1))}, {}, "has 9 rows, expected 10"),
        ({"x": np.zeros((10, 1)), "y": np.zeros((10, 1))}, {"loss": "l1"}, "loss 'l1' unknown"),
        ({"x": np.zeros((10, 1)), "y": np.zeros((10, 1))}, {"epochs": 0}, "epochs must be a positive int"),
        ({"x": np.zeros((10, 1)), "y": np.zeros((10, 1))}, {"val_fraction": 1.0}, "val_fraction"),
        ({"x": np.zeros((10, 1))}, {}, "no mechanism can be trained"),
        ({"x": np.zeros((10, 1)), "y": np.zeros((10, 1))}, {"variables": ["x"]}, "'x' is a root"),
    ],
)
def test_fit_rejects_bad_input(data, kwargs, match):
    with pytest.raises(ValueError, match=match):
        fit(WorldModel(graph()), data, **kwargs)
