"""The expected value of a gated site over a predicted switch: the mixture over the switch.

Oracle: the linear gated SCM of ``test_gated.py`` with ``a`` an action, ``c ~ Bernoulli(pi)``,
``pi = sigmoid(a - 0.5)``, ``x | c = 1 ~ Normal(2b + 0.5, exp(0.3b - 1))``, ``x | c = 0 ~
Normal(0.5b, 0.05)``, so by hand ``E[x] = pi f_1 + (1 - pi) f_0`` and ``Var x = pi (s_1^2 + f_1^2)
+ (1 - pi) (s_0^2 + f_0^2) - E[x]^2``. A dynamic twin (``p = p_prev + x``) checks rollouts.
Everything runs in float64 so that 1e-6 is a tolerance on the algebra, not on rounding.
"""

import math

import pytest
import torch

from models import (
    BernoulliMechanism,
    CausalGraph,
    EnsembleMechanism,
    GatedMechanism,
    HeteroscedasticMechanism,
    LinearMechanism,
    Variable,
    WorldModel,
)

FLOOR = 0.05
TOL = 1e-6
A = torch.tensor([[0.3], [-1.0], [0.0], [2.5]], dtype=torch.float64)
B = torch.tensor([[0.7], [-0.2], [1.5], [0.1]], dtype=torch.float64)


def static_model(weight=1.0, bias=-0.5):
    """a (action) -> c (Bernoulli, logit ``weight * a + bias``), b -> x, c -> x; x gated by c."""
    graph = CausalGraph(
        [
            Variable("a", "action", bounds=(-3.0, 3.0)),
            Variable("b", "observed"),
            Variable("c", "latent"),
            Variable("x", "latent"),
        ],
        [("a", "c"), ("b", "x"), ("c", "x")],
    )
    on = HeteroscedasticMechanism.from_coefficients(
        [[2.0, 0.0]], 0.5, log_scale_weight=[[0.3, 0.0]], log_scale_bias=-1.0
    )
    off = LinearMechanism.from_coefficients([[0.5, 0.0]], 0.0)
    mechs = {
        "c": BernoulliMechanism.from_coefficients([weight], bias),
        "x": GatedMechanism("c", on, FLOOR, off),
    }
    return WorldModel(graph, mechs).double()


def by_hand(a, b):
    """``(pi, f_1, s_1, f_0)`` of the oracle, each ``(N, 1)``."""
    return torch.sigmoid(a - 0.5), 2 * b + 0.5, torch.exp(0.3 * b - 1), 0.5 * b


def test_the_expected_value_and_sd_are_those_of_the_mixture_over_the_switch():
    model = static_model()
    assert model.mechanism("x").switch_index == 1  # parents (b, c)
    pi, f1, s1, f0 = by_hand(A, B)
    mean = pi * f1 + (1 - pi) * f0
    var = pi * (s1**2 + f1**2) + (1 - pi) * (FLOOR**2 + f0**2) - mean**2
    out = model.predict({"a": A, "b": B})
    torch.testing.assert_close(out["x"], mean, atol=TOL, rtol=0)
    # the switch's own value is its mode
    assert out["c"][:, 0].tolist() == [0.0, 0.0, 0.0, 1.0]
    sd = model.predict_scale({"a": A, "b": B})
    torch.testing.assert_close(sd["x"], var.sqrt(), atol=TOL, rtol=0)
    # without an ensemble the switch's uncertainty is all aleatoric
    torch.testing.assert_close(
        model.predict_scale({"a": A, "b": B}, "aleatoric")["x"], var.sqrt(), atol=TOL, rtol=0
    )
    assert torch.equal(
        model.predict_scale({"a": A, "b": B}, "epistemic")["x"], torch.zeros(4, 1, dtype=A.dtype)
    )
    # the mechanism's own method, with pi given
    pa = torch.cat([B, torch.zeros_like(B)], -1)
    torch.testing.assert_close(model.mechanism("x").mixture_loc(pa, pi), mean, atol=TOL, rtol=0)


def test_the_prediction_has_the_gradient_of_pi_in_an_action_that_only_moves_the_switch():
    model = static_model()
    a = A.clone().requires_grad_(True)
    x = model.predict({"a": a, "b": B}, grad=True)["x"]
    (grad,) = torch.autograd.grad(x.sum(), a)
    pi, f1, _, f0 = by_hand(A, B)
    torch.testing.assert_close(grad, pi * (1 - pi) * (f1 - f0), atol=TOL, rtol=0)
    assert bool((grad.abs() > 1e-3).all())
    h = 1e-5
    fd = (model.predict({"a": A + h, "b": B})["x"] - model.predict({"a": A - h, "b": B})["x"]) / (2 * h)
    torch.testing.assert_close(grad, fd, atol=1e-7, rtol=0)
    # the sd is differentiable too, and finite
    sd = model.predict_scale({"a": a, "b": B}, grad=True)["x"]
    (g_sd,) = torch.autograd.grad(sd.sum(), a)
    assert bool(torch.isfinite(g_sd).all()) and bool((g_sd != 0).all())


def test_a_given_switch_or_a_given_residual_keeps_the_exact_branch():
    model = static_model()
    c = torch.tensor([[1.0], [0.0], [0.0], [1.0]], dtype=torch.float64)
    _, f1, s1, f0 = by_hand(A, B)
    branch = torch.where(c == 1, f1, f0)
    torch.testing.assert_close(model.predict({"a": A, "b": B, "c": c})["x"], branch, atol=TOL, rtol=0)
    sd = model.predict_scale({"a": A, "b": B, "c": c})["x"]
    torch.testing.assert_close(sd, torch.where(c == 1, s1, torch.full_like(s1, FLOOR)), atol=TOL, rtol=0)
    # zero residuals given for every site, Gumbels included: the mode's branch, not the mixture
    eps = {"c": torch.zeros(4, 2, dtype=A.dtype), "x": torch.zeros(4, 1, dtype=A.dtype)}
    out = model.predict({"a": A, "b": B}, noise=eps)
    torch.testing.assert_close(out["x"], torch.where(out["c"] == 1, f1, f0), atol=TOL, rtol=0)
    assert not torch.allclose(out["x"], model.predict({"a": A, "b": B})["x"], atol=1e-3)


def dynamic_model(biases=(0.3,)):
    """a (action), p_prev -> c; p_prev, c -> x (gated, f_1 = b_k - 0.5 p_prev, f_0 = 0); p = p_prev + x."""
    graph = CausalGraph(
        [
            Variable("a", "action", bounds=(-3.0, 3.0)),
            Variable("p_prev", "observed", lag=1, lag_of="p"),
            Variable("c", "latent"),
            Variable("x", "latent"),
            Variable("p", "latent"),
        ],
        [("a", "c"), ("p_prev", "c"), ("p_prev", "x"), ("c", "x"), ("p_prev", "p"), ("x", "p")],
    )
    members = [
        HeteroscedasticMechanism.from_coefficients([[-0.5, 0.0]], b, log_scale_bias=math.log(0.1))
        for b in biases
    ]
    on = members[0] if len(members) == 1 else EnsembleMechanism(members)
    mechs = {
        "c": BernoulliMechanism.from_coefficients([2.0, -1.0], 0.2),
        "x": GatedMechanism("c", on, FLOOR),
        "p": LinearMechanism.from_coefficients([[1.0, 1.0]], 0.0, sigma=1e-3),
    }
    return WorldModel(graph, mechs).double()


ACTS = torch.tensor([[[0.4], [-0.3]], [[-2.0], [1.0]], [[1.5], [0.2]]], dtype=torch.float64)  # (N, H, 1)
P0 = torch.tensor([[0.1], [-0.4], [0.8]], dtype=torch.float64)


def rolled_by_hand(bias, p0=P0, acts=ACTS):
    """``(x, p)`` ``(N, H, 1)`` of the expected recursion of :func:`dynamic_model`."""
    p, xs, ps = p0, [], []
    for t in range(acts.shape[1]):
        pi = torch.sigmoid(2 * acts[:, t] - p + 0.2)
        x = pi * (bias - 0.5 * p)
        p = p + x
        xs.append(x)
        ps.append(p)
    return torch.stack(xs, 1), torch.stack(ps, 1)


def test_a_two_step_rollout_mixes_at_every_step_and_carries_the_gradient():
    model = dynamic_model()
    assert model.mechanism("x").switch_index == 1  # parents (p_prev, c)
    acts = ACTS.clone().requires_grad_(True)
    out = model.rollout({"p_prev": P0}, {"a": acts}, grad=True)
    x, p = rolled_by_hand(0.3)
    torch.testing.assert_close(out["x"], x, atol=TOL, rtol=0)
    torch.testing.assert_close(out["p"], p, atol=TOL, rtol=0)
    # the final position depends on the first action through pi_1 and through p_1 in step 2
    (grad,) = torch.autograd.grad(out["p"][:, -1].sum(), acts)
    h = 1e-5
    bump = torch.zeros_like(ACTS)
    bump[:, 0] = h
    fd = (rolled_by_hand(0.3, acts=ACTS + bump)[1] - rolled_by_hand(0.3, acts=ACTS - bump)[1])[:, -1] / (
        2 * h
    )
    torch.testing.assert_close(grad[:, 0], fd, atol=1e-7, rtol=0)
    assert bool((grad[:, 0].abs() > 1e-4).all())


def test_members_mix_with_their_own_pi_along_their_own_trajectories():
    biases = (0.3, 0.9)
    model = dynamic_model(biases)
    out = model.rollout({"p_prev": P0}, {"a": ACTS}, members=True)
    assert out["x"].shape == (2, 3, 2, 1)
    for k, b in enumerate(biases):
        x, p = rolled_by_hand(b)
        torch.testing.assert_close(out["x"][k], x, atol=TOL, rtol=0)
        torch.testing.assert_close(out["p"][k], p, atol=TOL, rtol=0)
    # one step: member k mixes its own on-branch mean; without members, the ensemble's mean
    one = model.predict({"p_prev": P0, "a": ACTS[:, 0]}, members=True)["x"]
    pi = torch.sigmoid(2 * ACTS[:, 0] - P0 + 0.2)
    for k, b in enumerate(biases):
        torch.testing.assert_close(one[k], pi * (b - 0.5 * P0), atol=TOL, rtol=0)
    mean = model.predict({"p_prev": P0, "a": ACTS[:, 0]})["x"]
    torch.testing.assert_close(mean, one.mean(0), atol=TOL, rtol=0)


def test_the_mixture_sd_splits_into_the_switch_as_aleatoric_and_the_weighted_spread_as_epistemic():
    biases = (0.3, 0.9)
    model = dynamic_model(biases)
    vals = {"p_prev": P0, "a": ACTS[:, 0]}
    pi = torch.sigmoid(2 * ACTS[:, 0] - P0 + 0.2)
    m = torch.stack([b - 0.5 * P0 for b in biases])  # (K, N, 1) member means of the on branch
    f1, spread = m.mean(0), m.var(0, unbiased=False)
    aleatoric = pi * 0.1**2 + (1 - pi) * FLOOR**2 + pi * (1 - pi) * f1**2
    epistemic = pi * spread
    total = pi * (0.1**2 + spread + f1**2) + (1 - pi) * FLOOR**2 - (pi * f1) ** 2
    torch.testing.assert_close(total, aleatoric + epistemic, atol=1e-12, rtol=0)  # the hand algebra
    for component, var in (("total", total), ("aleatoric", aleatoric), ("epistemic", epistemic)):
        sd = model.predict_scale(vals, component)["x"]
        torch.testing.assert_close(sd, var.sqrt(), atol=TOL, rtol=0)


def test_saturated_switches_give_finite_values_and_gradients():
    model = static_model(weight=80.0, bias=0.0)  # pi = sigmoid(80 a): 0 or 1 in float64 at a = -3, 3
    a = torch.tensor([[-3.0], [3.0], [0.0]], dtype=torch.float64, requires_grad=True)
    b = torch.tensor([[0.7], [0.7], [0.7]], dtype=torch.float64)
    x = model.predict({"a": a, "b": b}, grad=True)["x"]
    _, f1, _, f0 = by_hand(a.detach(), b)
    torch.testing.assert_close(x[:2].detach(), torch.cat([f0[:1], f1[1:2]]), atol=TOL, rtol=0)
    for component in ("total", "aleatoric", "epistemic"):
        sd = model.predict_scale({"a": a, "b": b}, component, grad=True)["x"]
        (g,) = torch.autograd.grad((x + sd).sum(), a, retain_graph=True)
        assert bool(torch.isfinite(sd).all()) and bool(torch.isfinite(g).all())


@pytest.mark.parametrize(
    ("p_on", "match"),
    [
        (torch.full((4, 1), 1.5, dtype=torch.float64), "must lie in \\[0, 1\\], got 1.5"),
        (torch.full((4, 1), float("nan"), dtype=torch.float64), "must lie in \\[0, 1\\], got nan"),
        (torch.full((4, 2), 0.5, dtype=torch.float64), "p_on has shape \\(4, 2\\), expected \\(..., 1\\)"),
        (
            torch.full((3, 1), 0.5, dtype=torch.float64),
            "does not broadcast against the parents' rows \\(4,\\)",
        ),
    ],
    ids=["above-1", "nan", "two-columns", "rows"],
)
def test_a_bad_switch_probability_is_refused(p_on, match):
    mech = static_model().mechanism("x")
    pa = torch.cat([B, torch.zeros_like(B)], -1)
    with pytest.raises(ValueError, match=match):
        mech.mixture_loc(pa, p_on)


def test_an_unbound_gated_mechanism_cannot_mix():
    mech = GatedMechanism("c", LinearMechanism.from_coefficients([[1.0, 0.0]]), FLOOR)
    with pytest.raises(ValueError, match="switch 'c' is not bound to a parent column"):
        mech.mixture_loc(torch.zeros(2, 2), torch.full((2, 1), 0.5))
