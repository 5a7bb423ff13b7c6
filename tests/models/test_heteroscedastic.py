"""Heteroscedastic mechanisms: X ~ Normal(f(pa), sigma(pa)) with a soft-clamped log-scale."""

import math

import pyro
import pytest
import torch
import torch.nn.functional as F

from models import CausalGraph, HeteroscedasticMechanism, LinearMechanism, Variable, WorldModel, finger_graph
from models.heteroscedastic import LOG_SCALE_BOUNDS, OFFSET_LIMIT, soft_clamp
from models.mechanisms import make_mechanism


def xy_graph():
    return CausalGraph([Variable("x", "observed"), Variable("y", "latent")], [("x", "y")])


def test_soft_clamp_keeps_the_log_scale_inside_its_bounds_and_is_smooth():
    s = torch.linspace(-50, 50, 1001, requires_grad=True)
    low, high = torch.tensor(-2.0), torch.tensor(1.0)
    out = soft_clamp(s, low, high)
    values = out.detach()
    # lower bound hard, upper bound soft: s < low + softplus(high - low) = high + 0.049 here
    assert float(values.min()) >= -2.0 and float(values.max()) <= float(low + F.softplus(high - low))
    # the PETS clamp, written out
    expected = low + F.softplus((high - F.softplus(high - s)) - low)
    torch.testing.assert_close(out, expected)
    # far inside the bounds it is the identity
    mid = soft_clamp(torch.tensor([-0.5]), torch.tensor(-30.0), torch.tensor(30.0))
    assert float(mid) == pytest.approx(-0.5, abs=1e-6)
    out.sum().backward()  # after the checks on the values
    assert torch.isfinite(s.grad).all() and (s.grad >= 0).all()


def test_from_coefficients_is_the_closed_form():
    mech = HeteroscedasticMechanism.from_coefficients(
        [[2.0, -1.0]], bias=0.5, log_scale_weight=[[0.3, 0.1]], log_scale_bias=-1.0
    )
    pa = torch.tensor([[1.0, 2.0], [-1.0, 0.5]])
    loc, scale = mech.loc_scale(pa)
    torch.testing.assert_close(loc, (2.0 * pa[:, :1] - pa[:, 1:] + 0.5))
    torch.testing.assert_close(scale, torch.exp(0.3 * pa[:, :1] + 0.1 * pa[:, 1:] - 1.0), rtol=1e-6, atol=0)
    torch.testing.assert_close(mech(pa), loc)
    assert mech.heteroscedastic and mech.trainable
    with pytest.raises(ValueError, match="heteroscedastic: its scale depends on the parents"):
        _ = mech.sigma
    with pytest.raises(ValueError, match="cannot be set"):
        mech.set_sigma(1.0)


def test_the_scale_lives_in_standardised_units():
    mech = HeteroscedasticMechanism(1, 1, hidden=(4,), seed=0)
    pa = torch.tensor([[0.3], [1.2]])
    m0, s0 = mech.loc_scale(pa)
    mech.set_normalization([1.0], [2.0], [5.0], [10.0])
    m1, s1 = mech.loc_scale(1.0 + 2.0 * pa)
    torch.testing.assert_close(m1, 5.0 + 10.0 * m0)
    torch.testing.assert_close(s1, 10.0 * s0)
    torch.testing.assert_close(mech.log_scale(1.0 + 2.0 * pa), torch.log(s0))


def test_default_bounds_and_learned_bound_penalty():
    mech = HeteroscedasticMechanism(2, 3, seed=0)
    torch.testing.assert_close(mech.log_scale_min.detach(), torch.full((3,), LOG_SCALE_BOUNDS[0]))
    torch.testing.assert_close(mech.log_scale_max.detach(), torch.full((3,), LOG_SCALE_BOUNDS[1]))
    assert isinstance(mech.log_scale_max, torch.nn.Parameter)
    assert float(mech.penalty().detach()) == pytest.approx(
        0.01 * 3 * (LOG_SCALE_BOUNDS[1] - LOG_SCALE_BOUNDS[0])
    )
    fixed = HeteroscedasticMechanism(2, 1, learn_bounds=False, log_scale_bounds=(-3, 0), seed=0)
    assert "log_scale_min" in dict(fixed.named_buffers()) and float(fixed.penalty()) == 0.0
    s = fixed.log_scale(torch.randn(100, 2, generator=torch.Generator().manual_seed(0)) * 100).detach()
    assert float(s.min()) >= -3.0 and float(s.max()) <= -3.0 + math.log1p(math.exp(3.0))


def test_config_round_trip_and_seeded_weights():
    a = HeteroscedasticMechanism(2, 1, hidden=(5,), activation="relu", log_scale_bounds=(-4, 2), seed=3)
    b = make_mechanism(a.config(), seed=3)
    assert isinstance(b, HeteroscedasticMechanism) and b.config() == a.config()
    assert a.config()["log_scale_bounds"] == [-4.0, 2.0] and a.config()["learn_bounds"] is True
    for (k, x), (_, y) in zip(a.state_dict().items(), b.state_dict().items(), strict=True):
        assert torch.equal(x, y), k


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"log_scale_bounds": (1.0, -1.0)}, "log_scale_bounds must have low < high, got (1, -1)"),
        ({"log_scale_bounds": (0.0, 0.0)}, "log_scale_bounds must have low < high"),
        ({"log_scale_bounds": (float("nan"), 1.0)}, "log_scale_bounds[0] must be a finite number, got nan"),
        ({"log_scale_bounds": (-1.0, float("inf"))}, "log_scale_bounds[1] must be a finite number, got inf"),
        ({"log_scale_bounds": 3.0}, "log_scale_bounds must be a pair (low, high)"),
        ({"log_scale_bounds": (1.0, 2.0, 3.0)}, "log_scale_bounds must be a pair (low, high)"),
        ({"learn_bounds": "yes"}, "learn_bounds must be"),
        ({"activation": "gelu"}, "activation 'gelu' unknown"),
        ({"hidden": (0,)}, "hidden"),
    ],
)
def test_bad_arguments_name_the_value(kwargs, match):
    with pytest.raises(ValueError, match=match.replace("(", r"\(").replace(")", r"\)").replace("[", r"\[")):
        HeteroscedasticMechanism(1, 1, **kwargs)


def test_the_program_site_is_a_normal_with_a_per_unit_scale():
    mech = HeteroscedasticMechanism.from_coefficients(1.5, 0.0, log_scale_weight=0.5, log_scale_bias=-0.2)
    m = WorldModel(xy_graph(), {"y": mech})
    x = torch.tensor([[-1.0], [0.0], [2.0]])
    y = torch.tensor([[0.1], [-0.3], [2.5]])
    tr = pyro.poutine.trace(m).get_trace({"x": x, "y": y})
    fn = tr.nodes["y"]["fn"]
    scale = torch.exp(0.5 * x - 0.2)
    expected = torch.distributions.Normal(1.5 * x, scale).log_prob(y).sum(-1)
    torch.testing.assert_close(fn.log_prob(y), expected)
    # residuals and predict with them invert each other
    eps = m.residuals({"x": x, "y": y})
    torch.testing.assert_close(eps["y"], (y - 1.5 * x) / scale)
    torch.testing.assert_close(m.predict({"x": x}, noise=eps)["y"], y)
    with pytest.raises(ValueError, match="heteroscedastic"):
        m.sigma("y")


def test_world_model_kind_hetero_builds_seeded_heteroscedastic_mechanisms():
    m = WorldModel(finger_graph("state"), kind="hetero", hidden=(8,), seed=2)
    mech = m.mechanism("dq.finger")
    assert isinstance(mech, HeteroscedasticMechanism) and mech.hidden == (8,)
    again = WorldModel(finger_graph("state"), kind="hetero", hidden=(8,), seed=2)
    for (k, a), (_, b) in zip(m.state_dict().items(), again.state_dict().items(), strict=True):
        assert torch.equal(a, b), k
    values = {"act.finger": torch.zeros(3, 1), "q_prev.finger": torch.linspace(-1, 1, 3)[:, None]}
    scales = m.predict_scale(values)
    assert set(scales) == {"dq.finger", "q.finger"} and scales["dq.finger"].shape == (3, 1)
    assert (scales["q.finger"] > 0).all()


def test_with_graph_rewires_a_heteroscedastic_mechanism():
    m = WorldModel(finger_graph("thesis"), kind="hetero", hidden=(6,), seed=0)
    bigger = m.with_graph(finger_graph("state"), seed=1)
    assert bigger.provenance["warm_start"]["dq.finger"] == "rewired"
    values = {"act.finger": torch.tensor([[0.1], [-0.4]]), "q_prev.finger": torch.tensor([[0.7], [-1.0]])}
    a = m.mechanism("dq.finger").loc_scale(values["act.finger"])
    b = bigger.mechanism("dq.finger").loc_scale(
        torch.cat([values["act.finger"], values["q_prev.finger"]], -1)
    )
    for x, y in zip(a, b, strict=True):
        torch.testing.assert_close(x, y)
    # no trunk: both heads are rewired
    lin = WorldModel(finger_graph("thesis"), kind="hetero", hidden=(), seed=0).with_graph(
        finger_graph("state")
    )
    assert lin.provenance["warm_start"]["dq.finger"] == "rewired"


def test_a_homoscedastic_mechanism_reports_its_sigma_as_the_scale():
    mech = LinearMechanism.from_coefficients([[1.0]], sigma=0.25)
    _, scale = mech.loc_scale(torch.zeros(4, 1))
    assert scale.shape == (4, 1) and torch.all(scale == 0.25)
    assert not mech.heteroscedastic and math.isclose(float(mech.sigma.detach()), 0.25, rel_tol=1e-6)


def test_learned_bounds_only_move_inward_and_offsets_stay_within_their_limit(caplog):
    mech = HeteroscedasticMechanism(2, 2, hidden=(4,), log_scale_bounds=(-3.0, 0.5), seed=0)
    with torch.no_grad():  # as if training had dragged the bounds outward
        mech.log_scale_min.copy_(torch.tensor([-40.0, -1.0]))
        mech.log_scale_max.copy_(torch.tensor([9.0, 0.2]))
    low, high = mech.scale_bounds()
    torch.testing.assert_close(low, torch.tensor([-3.0, -1.0]))
    torch.testing.assert_close(high, torch.tensor([0.5, 0.2]))
    s = mech.log_scale(torch.randn(200, 2, generator=torch.Generator().manual_seed(1)) * 50).detach()
    assert float(s[:, 0].min()) >= -3.0 and float(s[:, 1].min()) >= -1.0
    with caplog.at_level("WARNING", logger="models.heteroscedastic"):
        for _ in range(5):  # factors of 1e-6, as held-out residuals that are all 0 give
            mech.recalibrate([1e-6, 1.0])
    assert float(mech.log_scale_offset[0]) == pytest.approx(-OFFSET_LIMIT)
    assert float(mech.log_scale_offset[1]) == 0.0
    assert "exceed" in caplog.text
    mech.reset_recalibration()
    assert float(mech.log_scale_offset.abs().max()) == 0.0
