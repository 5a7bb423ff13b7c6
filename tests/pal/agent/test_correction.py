"""The online correction from abducted residuals: exact abduction, the filter's closed form on a biased linear plant."""

import numpy as np
import pytest
import torch

from inference import ActionOptions, ReplayNoise, SamplingConfig, infer_action
from models import CausalGraph, LinearMechanism, Variable, WorldModel
from pal.agent import CorrectionConfig
from pal.agent.correction import Correction, abduct

SIGMA = 0.05


def _linear_model():
    """x = x_prev + a + SIGMA u: the model; the plant adds a bias b that the model lacks."""
    graph = CausalGraph(
        [
            Variable("a", "action", bounds=(-2.0, 2.0)),
            Variable("x_prev", "observed", lag=1, lag_of="x"),
            Variable("x", "latent"),
        ],
        [("a", "x"), ("x_prev", "x")],
    )
    return WorldModel(graph, {"x": LinearMechanism.from_coefficients([[1.0, 1.0]], sigma=SIGMA)})


def test_abduction_is_exact_per_site():
    model = _linear_model()
    u = abduct(model, {"a": np.array([0.3]), "x_prev": np.array([1.0]), "x": np.array([1.4])}, ("x",))
    np.testing.assert_allclose(u["x"], [(1.4 - 1.3) / SIGMA], atol=1e-5)  # float32 model
    with pytest.raises(ValueError, match=r"needs the values of \['x'\]"):
        abduct(model, {"a": np.array([0.3]), "x_prev": np.array([1.0])}, ("x",))


@pytest.mark.parametrize("gain", [1.0, 0.5])
def test_a_bias_falls_as_the_closed_form_and_below_one_percent_in_ten_steps(gain):
    """Controller a = x* - (prediction at a = 0 with uhat replayed); offset_n = (1 - g)^(n-1) b."""
    model, bias, target = _linear_model(), 0.2, 0.5
    corr = Correction(CorrectionConfig(enabled=True, window=3, gain=gain, sites=("x",)))
    x, offsets = 0.0, []
    for _ in range(10):
        noise = corr.noise(model)
        values = {"a": torch.zeros(1, 1, dtype=model.dtype), "x_prev": torch.tensor([[x]], dtype=model.dtype)}
        eps = {"x": torch.as_tensor(noise["x"][None])} if noise else "expected"
        free = float(model.predict(values, noise=eps)["x"][0, 0])
        a = target - free
        new = x + a + bias
        corr.update(
            abduct(model, {"a": np.array([a]), "x_prev": np.array([x]), "x": np.array([new])}, ("x",))
        )
        x = new
        offsets.append(x - target)
    closed = [bias * (1 - gain) ** n for n in range(10)]
    np.testing.assert_allclose(offsets, closed, atol=1e-6)  # float32 model
    assert abs(offsets[-1]) < 0.01 * abs(offsets[0])


def test_planning_replays_the_given_residuals_and_switches_off():
    model, x, uhat = _linear_model(), 0.1, 4.0
    options = ActionOptions(
        scale=0.01, sampling=SamplingConfig(population=64, elites=8, iterations=3, refine_steps=50)
    )
    state, targets = {"x_prev": [[x]]}, {"x": [[0.5]]}
    a_plain = float(infer_action(model, state, targets, options=options, seed=0).actions["a"][0, 0])
    replayed = ReplayNoise({"x": torch.tensor([[uhat]], dtype=model.dtype)}, default="expected")(model)
    a_corr = float(infer_action(replayed, state, targets, options=options, seed=0).actions["a"][0, 0])
    assert abs(a_plain - 0.4) < 2e-3
    assert abs(a_corr - (0.4 - SIGMA * uhat)) < 2e-3
    off = Correction(CorrectionConfig(enabled=False, sites=("x",)))
    off.observe(model, {"x_prev": np.array([0.0])}, np.array([0.0]), None)
    assert off.noise(model) is None


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"window": 0}, "correction.window is 0"),
        ({"window": 1.5}, "correction.window is 1.5"),
        ({"gain": 0.0}, "correction.gain"),
        ({"sites": ()}, "correction.sites"),
    ],
)
def test_bad_correction_settings_are_refused_naming_the_value(kwargs, match):
    with pytest.raises(ValueError, match=match):
        CorrectionConfig(**kwargs)
