"""ModelWorld against a closed-form linear SCM: x(t+1) = x(t) + a(t) + u(t), u ~ N(0, s²)."""

import pytest
import torch

from models.graph import CausalGraph
from models.mechanisms import LinearMechanism
from models.variables import Variable
from models.world import WorldModel
from pal.language.world import ModelWorld, Situations

S_NOISE = 0.5


def _world() -> ModelWorld:
    g = CausalGraph(
        [
            Variable("x_prev", "observed", lag=1, lag_of="x"),
            Variable("a", "action", bounds=(-2, 2)),
            Variable("x", "latent"),
        ],
        [("x_prev", "x"), ("a", "x")],
    )
    mech = LinearMechanism.from_coefficients([[1.0, 1.0]], 0.0, S_NOISE)
    return ModelWorld(WorldModel(g, {"x": mech}).double())


def test_outcome_moments_and_twin_noise():
    world = _world()
    sit = Situations({"x": torch.zeros(3, 1, dtype=torch.float64)})
    p1 = torch.full((3, 4, 1), 0.5, dtype=torch.float64)
    p2 = torch.zeros(3, 4, 1, dtype=torch.float64)
    o1, o2 = world.play(sit, [p1, p2], 2000, torch.Generator().manual_seed(0))
    assert o1.shape == (3, 2000, 5)
    end = o1.at("end")["x"]
    # mean T a = 2, variance T s² = 1; se of the mean 1/sqrt(6000), of the variance ~ sqrt(2/6000)
    assert abs(float(end.mean()) - 2.0) < 4 / 6000**0.5
    assert abs(float(end.var()) - 1.0) < 4 * (2 / 6000) ** 0.5
    # twin worlds: a linear model's outcomes differ exactly by the summed plan difference
    diff = o1.paths["x"] - o2.paths["x"]
    assert torch.allclose(diff[:, :, -1], torch.full_like(diff[:, :, -1], 2.0), atol=1e-12)
    assert "a" in o1.unknown_start and "a" not in o1.at("start")


def test_bad_plans_and_start_values():
    world = _world()
    sit = Situations({"x": torch.zeros(3, 1, dtype=torch.float64)})
    with pytest.raises(ValueError, match=r"plans\[0\] has shape"):
        world.play(sit, [torch.zeros(2, 4, 1, dtype=torch.float64)], 1, torch.Generator())
    with pytest.raises(ValueError, match="lag-1 slot"):
        world.play(
            Situations({"a": torch.zeros(3, 1, dtype=torch.float64)}),
            [torch.zeros(3, 1, 1)],
            1,
            torch.Generator(),
        )
    with pytest.raises(ValueError, match="not variables of the model graph"):
        world.play(
            Situations({"x": torch.zeros(3, 1), "zz": torch.zeros(3, 1)}),
            [torch.zeros(3, 1, 1)],
            1,
            torch.Generator(),
        )


def test_held_values_outside_the_model_stay_at_their_start():
    world = _world()
    g = torch.tensor([[1.0, 2.0], [3.0, 4.0], [5.0, 6.0]], dtype=torch.float64)
    sit = Situations({"x": torch.zeros(3, 1, dtype=torch.float64), "goal": g})
    with pytest.raises(ValueError, match="not variables of the model graph nor held"):
        world.play(sit, [torch.zeros(3, 2, 1)], 1, torch.Generator())
    held = ModelWorld(world.model, held=("goal",))
    (out,) = held.play(sit, [torch.ones(3, 2, 1, dtype=torch.float64)], 4, torch.Generator().manual_seed(0))
    assert out.paths["goal"].shape == (3, 4, 3, 2)
    torch.testing.assert_close(out.paths["goal"], g[:, None, None, :].expand(3, 4, 3, 2), rtol=0, atol=0)
    assert out.at("end")["goal"].shape == (3, 4, 2)
    # the model's own variables are rolled out, not held
    with pytest.raises(ValueError, match="variables of the model"):
        ModelWorld(world.model, held=("x",))
    with pytest.raises(ValueError, match="sequence of variable names"):
        ModelWorld(world.model, held="goal")
