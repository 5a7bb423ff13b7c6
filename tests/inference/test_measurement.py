"""Measurement sites with per-frame uncertainty: o_obs ~ Normal(o, sigma_t)."""

import pytest
import torch

from inference import MeasurementScale, infer_state
from models import CausalGraph, LinearMechanism, Role, Variable, WorldModel


@pytest.fixture
def sensor():
    """x -> o -> meas with o = x + U_o (sigma 1) and meas = o + noise (sigma given per unit)."""
    graph = CausalGraph(
        [Variable("x", Role.OBSERVED), Variable("o", Role.LATENT), Variable("meas", Role.OBSERVED)],
        [("x", "o"), ("o", "meas")],
    )
    one = LinearMechanism.from_coefficients([[1.0]])
    return WorldModel(graph, {"o": one, "meas": LinearMechanism.from_coefficients([[1.0]], sigma=5.0)})


@pytest.mark.slow
def test_posterior_weights_each_frame_by_its_own_uncertainty(sensor):
    # closed form: o | x, m ~ N((x + m / s^2) / (1 + 1 / s^2), 1 / (1 + 1 / s^2))
    x = torch.tensor([[0.0], [0.0], [1.0]])
    m = torch.tensor([[2.0], [2.0], [-1.0]])
    s = torch.tensor([[0.5], [2.0], [1.0]])
    post = infer_state(MeasurementScale({"meas": s})(sensor), {"x": x, "meas": m}, num_steps=800, seed=0)
    precision = 1 + 1 / s**2
    mean = (x + m / s**2) / precision
    sd = precision.rsqrt()
    torch.testing.assert_close(post.mean["o"], mean, atol=0.03, rtol=0)
    torch.testing.assert_close(post.sd["o"], sd, atol=0, rtol=0.1)


@pytest.mark.slow
def test_without_a_scale_the_learned_sigma_is_used(sensor):
    x, m = torch.zeros(1, 1), torch.full((1, 1), 2.0)
    post = infer_state(sensor, {"x": x, "meas": m}, num_steps=800, seed=0)
    # learned sigma 5: o | x, m ~ N((m / 25) / (1 + 1 / 25), ...)
    assert post.mean["o"].item() == pytest.approx((2 / 25) / (1 + 1 / 25), abs=0.03)


@pytest.mark.parametrize(
    ("scales", "match"),
    [
        ({"meas": torch.tensor([[0.0]])}, "finite and > 0"),
        ({"meas": torch.tensor([[float("nan")]])}, "finite and > 0"),
        ({"meas": torch.tensor(1.0)}, "\\(dim,\\) or \\(N, dim\\)"),
        ({"meas": torch.ones(2, 1)}, "has shape \\(2, 1\\), expected \\(1,\\) or \\(1, 1\\)"),
        ({"o": torch.ones(1, 1)}, "not observed sites"),
    ],
)
def test_bad_scales(sensor, scales, match):
    with pytest.raises(ValueError, match=match):
        infer_state(MeasurementScale(scales)(sensor), {"x": torch.zeros(1, 1), "meas": torch.ones(1, 1)})


def test_handler_rejects_a_mismatched_shape(sensor):
    program = MeasurementScale({"meas": torch.ones(2)})(sensor)
    with pytest.raises(ValueError, match="expected \\(1,\\) or \\(3, 1\\)"):
        program({"x": torch.zeros(3, 1), "meas": torch.ones(3, 1)}, 3)
