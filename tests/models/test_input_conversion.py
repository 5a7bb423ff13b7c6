"""Floating input of any precision is converted to the model's dtype; bounds have a tolerance."""

from __future__ import annotations

import numpy as np
import pyro
import pytest
import torch

from models import CausalGraph, LinearMechanism, MLPMechanism, Variable, WorldModel, chain_graph, finger_graph
from models.world import BOUNDS_TOLERANCE


@pytest.fixture
def chain():
    return WorldModel(
        chain_graph(),
        {"y": LinearMechanism.from_coefficients([[2.0]]), "z": LinearMechanism.from_coefficients([[-1.5]])},
    )


@pytest.mark.parametrize(
    "x",
    [
        torch.tensor([[1.0], [2.0]], dtype=torch.float64),
        torch.from_numpy(np.array([[1.0], [2.0]])),
        np.array([[1.0], [2.0]], dtype=np.float32),
        np.array([[1.0], [2.0]], dtype=np.float64),
        np.array([[1.0], [2.0]], dtype=np.float16),
        [[1.0], [2.0]],
        [[1], [2]],
    ],
    ids=["torch64", "from_numpy", "np32", "np64", "np16", "list", "list-of-ints"],
)
def test_predict_converts_floating_input_to_the_model_dtype(chain, x):
    out = chain.predict({"x": x})
    assert out["z"].dtype == torch.float32 and out["x"].dtype == torch.float32
    torch.testing.assert_close(out["z"], torch.tensor([[-3.0], [-6.0]]))


def test_every_world_model_entry_point_takes_float64(chain):
    x64 = torch.tensor([[1.0]], dtype=torch.float64)
    values = {"x": x64, "y": torch.tensor([[2.5]], dtype=torch.float64), "z": x64 * -3}
    eps = chain.residuals(values)
    assert eps["y"].dtype == torch.float32
    back = chain.predict({"x": x64}, noise={k: v.double() for k, v in eps.items()})
    torch.testing.assert_close(back["z"], torch.tensor([[-3.0]]))
    tr = pyro.poutine.trace(chain).get_trace(values)
    assert tr.nodes["y"]["value"].dtype == torch.float32
    chain.set_root_prior("x", np.float64(1.0), np.array([2.0]))
    assert chain.root_priors.get("x")[1].dtype == torch.float32
    assert chain.loc("y", {"x": x64}).dtype == torch.float32
    mech = MLPMechanism(1, 1, hidden=(3,), seed=0)
    assert mech(x64).dtype == torch.float32


def test_rollout_takes_float64_and_numpy():
    m = WorldModel(finger_graph("state"), seed=0, hidden=(4,))
    traj = m.rollout(
        {"q_prev.finger": np.zeros((2, 1))}, {"act.finger": torch.zeros(2, 3, 1, dtype=torch.float64)}
    )
    assert traj["q.finger"].shape == (2, 3, 1) and traj["q.finger"].dtype == torch.float32


def test_a_float64_model_takes_float32_input(chain):
    chain.double()
    assert chain.dtype == torch.float64
    out = chain.predict({"x": torch.tensor([[1.0]])})
    assert out["z"].dtype == torch.float64
    assert chain.sample(3, torch.Generator().manual_seed(0))["z"].dtype == torch.float64


def test_linear_coefficients_from_numpy_float64():
    mech = LinearMechanism.from_coefficients(
        np.array([[1.5, -2.0]]), bias=np.float64(0.5), sigma=np.array([0.1])
    )
    torch.testing.assert_close(mech(torch.tensor([[1.0, 1.0]])).detach(), torch.tensor([[0.0]]))


def bounded() -> WorldModel:
    g = CausalGraph([Variable("a", "action", bounds=(-1.0, 0.33)), Variable("y", "latent")], [("a", "y")])
    return WorldModel(g, {"y": LinearMechanism.from_coefficients([[1.0]])})


def test_actions_on_and_within_a_few_ulps_of_the_bounds_are_accepted():
    m = bounded()
    tol = BOUNDS_TOLERANCE
    edge = torch.tensor([[-1.0], [0.33], [0.33 + 0.5 * tol], [-1.0 - tol]])
    torch.testing.assert_close(m.predict({"a": edge})["y"], edge)
    m.rollout({}, {"a": edge[:, None]})


@pytest.mark.parametrize("value", [0.33 + 1e-5, -1.0 - 1e-5, 5.0])
def test_actions_clearly_outside_the_bounds_are_refused(value):
    m = bounded()
    with pytest.raises(
        ValueError, match=r"values\['a'\] has 1 entries outside the action bounds \[-1, 0.33\]"
    ):
        m.predict({"a": torch.tensor([[value]])})
