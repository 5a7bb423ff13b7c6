"""Discrete sites: Bernoulli and categorical mechanisms, Gumbel-max counterfactuals, fit, do, infer_*.

Oracles: the logistic closed form of the binary Gumbel-max SCM, numerical integration over the
Gumbel noise for three categories (scipy), and brute-force enumeration of the discrete states.
"""

import math

import numpy as np
import pytest
import torch
from scipy import integrate

from inference import (
    ActionOptions,
    FitSchedule,
    SamplingConfig,
    counterfactual,
    do,
    fit,
    infer_action,
    infer_state,
    simulate,
)
from models import (
    BernoulliMechanism,
    CategoricalMechanism,
    CausalGraph,
    LinearMechanism,
    Variable,
    WorldModel,
)
from models.discrete import CategoricalCode, gumbel_max, gumbel_posterior

S = 4_000_000  # draws: the sd of a probability estimate is <= 2.5e-4, 1e-3 is 4 sd


def sigmoid(v):
    return 1 / (1 + math.exp(-v))


def _gumbel_pdf(t):
    return math.exp(-t - math.exp(-t))


def _gumbel_cdf(t):
    return math.exp(-math.exp(-t))


def gumbel_joint(a, b):
    """P(argmax(a + G) = i, argmax(b + G) = j) for K = 3 by quadrature over the Gumbels."""
    k = len(a)
    out = np.zeros((k, k))
    for i in range(k):
        others = [m for m in range(k) if m != i]

        def diag(t, i=i, others=others):
            return _gumbel_pdf(t) * math.prod(_gumbel_cdf(t + min(a[i] - a[m], b[i] - b[m])) for m in others)

        out[i, i] = integrate.quad(diag, -10, 40, epsabs=1e-12, limit=200)[0]
        for j in others:
            (m,) = [q for q in range(k) if q not in (i, j)]
            if a[i] - a[j] <= b[i] - b[j]:
                continue

            def inner(gj, gi, i=i, j=j, m=m):
                return _gumbel_pdf(gj) * _gumbel_cdf(min(gi + a[i] - a[m], gj + b[j] - b[m]))

            out[i, j] = integrate.dblquad(
                lambda gj, gi, inner=inner: _gumbel_pdf(gi) * inner(gj, gi),
                -10,
                40,
                lambda gi, i=i, j=j: gi + b[i] - b[j],
                lambda gi, i=i, j=j: gi + a[i] - a[j],
                epsabs=1e-11,
            )[0]
    return out


def _graph(*names_edges):
    names, edges = names_edges
    return CausalGraph([Variable(n, "observed") for n in names], edges)


# ---------------------------------------------------------------------------- Gumbel-max
def test_gumbel_posterior_is_consistent_and_exact_in_distribution():
    logits = torch.tensor([[0.3, -0.5, 1.2]]).expand(200_000, 3)
    value = torch.full((200_000, 1), 1.0)
    g = gumbel_posterior(logits, value, torch.Generator().manual_seed(0))
    assert bool((gumbel_max(logits, g) == value).all())
    # the unconditional noise, re-weighted: P(argmax(l + G) = 1) averaged over the posterior of
    # each observed category reproduces a standard Gumbel's mean (Euler's constant)
    probs = torch.softmax(logits[0], 0)
    gen = torch.Generator().manual_seed(1)
    means = []
    for c in range(3):
        gc = gumbel_posterior(logits, torch.full((200_000, 1), float(c)), gen)
        means.append(gc.mean(0))
    mixture = sum(p * m for p, m in zip(probs, means, strict=True))
    torch.testing.assert_close(mixture, torch.full((3,), 0.5772156649), atol=1e-2, rtol=0)


def test_categorical_code_distribution():
    d = CategoricalCode(torch.tensor([[0.0, 1.0, -1.0], [2.0, 0.0, 0.0]]))
    assert d.batch_shape == (2,) and d.event_shape == (1,)
    v = torch.tensor([[1.0], [0.0]])
    expected = torch.log_softmax(d.logits, -1)[[0, 1], [1, 0]]
    torch.testing.assert_close(d.log_prob(v), expected)
    assert d.enumerate_support(expand=False).shape == (3, 1, 1)
    assert d.log_prob(d.enumerate_support(expand=False)).shape == (3, 2)


# ---------------------------------------------------------------------------- counterfactuals
@pytest.mark.slow
def test_bernoulli_counterfactual_matches_the_logistic_closed_form():
    """X -> T, logit P(T = 1) = 1.5 X - 0.2; do(X := x'): P(T' = 1 | T = t, x) in closed form."""
    model = WorldModel(
        _graph(["x", "t"], [("x", "t")]), {"t": BernoulliMechanism.from_coefficients([1.5], -0.2)}
    )
    x = torch.tensor([[0.4], [0.4], [-1.0]])
    t = torch.tensor([[1.0], [0.0], [1.0]])
    cf = counterfactual(model, {"x": x, "t": t}, [{"x": 1.2}, {"x": -0.8}], num_samples=S // 3)
    assert not cf.exact
    p = cf.probability("t", 1.0)  # (K, N)
    for k, x_new in enumerate((1.2, -0.8)):
        for u in range(3):
            lo, ln = 1.5 * float(x[u]) - 0.2, 1.5 * x_new - 0.2
            if t[u] == 1:
                exact = sigmoid(min(lo, ln)) / sigmoid(lo)
            else:
                exact = max(0.0, sigmoid(-lo) - sigmoid(-ln)) / sigmoid(-lo)
            assert float(p[k, u]) == pytest.approx(exact, abs=1e-3)


def test_three_category_counterfactual_matches_integration_over_the_gumbels():
    weight, bias = [[0.0], [1.0], [-1.5]], [0.0, 0.3, 0.1]
    model = WorldModel(
        _graph(["x", "c"], [("x", "c")]), {"c": CategoricalMechanism.from_coefficients(weight, bias)}
    )
    x0, x1 = 0.5, -0.7
    a = [w[0] * x0 + b for w, b in zip(weight, bias, strict=True)]
    b_ = [w[0] * x1 + b for w, b in zip(weight, bias, strict=True)]
    joint = gumbel_joint(a, b_)
    assert joint.sum() == pytest.approx(1.0, abs=1e-6)
    for c in range(3):
        cf = counterfactual(
            model, {"x": torch.tensor([[x0]]), "c": torch.tensor([[float(c)]])}, {"x": x1}, num_samples=S // 3
        )
        for j in range(3):
            exact = joint[c, j] / joint[c].sum()
            assert float(cf.probability("c", float(j))[0, 0]) == pytest.approx(exact, abs=1e-3)


def _mixed():
    """X -> C (3 categories) -> Y <- X, Y = beta_C + 0.5 X + 0.7 U (C one-hot)."""
    graph = _graph(["x", "c", "y"], [("x", "c"), ("x", "y"), ("c", "y")])
    beta = [1.0, -2.0, 0.5]
    # y's input: x then one-hot(c): weights [0.5, beta_0, beta_1, beta_2]
    mechs = {
        "c": CategoricalMechanism.from_coefficients([[0.0], [1.0], [-1.5]], [0.0, 0.3, 0.1]),
        "y": LinearMechanism.from_coefficients([[0.5, *beta]], 0.0, 0.7),
    }
    return WorldModel(graph, mechs), beta


def test_mixed_discrete_and_continuous_chain_matches_enumeration():
    model, beta = _mixed()
    assert model.parent_dim("y") == 4
    x0, c0, y0, x1 = 0.5, 1.0, -1.2, -0.7
    cf = counterfactual(
        model,
        {"x": torch.tensor([[x0]]), "c": torch.tensor([[c0]]), "y": torch.tensor([[y0]])},
        {"x": x1},
        num_samples=S // 3,
    )
    a = [0.0 * x0, 1.0 * x0 + 0.3, -1.5 * x0 + 0.1]
    b_ = [0.0 * x1, 1.0 * x1 + 0.3, -1.5 * x1 + 0.1]
    joint = gumbel_joint(a, b_)
    p = joint[int(c0)] / joint[int(c0)].sum()
    u = y0 - beta[int(c0)] - 0.5 * x0
    for j in range(3):
        assert float(cf.probability("c", float(j))[0, 0]) == pytest.approx(p[j], abs=1e-3)
        # every draw with C' = j has Y' = beta_j + 0.5 x' + u exactly
        ys = cf.samples["y"][:, 0, 0, 0][cf.samples["c"][:, 0, 0, 0] == j]
        torch.testing.assert_close(ys, torch.full_like(ys, beta[j] + 0.5 * x1 + u), atol=1e-5, rtol=0)
    expected = sum(p[j] * (beta[j] + 0.5 * x1 + u) for j in range(3))
    assert float(cf.mean["y"]) == pytest.approx(expected, abs=3 * 1e-3 * 3)


def test_a_latent_bernoulli_parent_is_enumerated_then_abducted():
    """X -> T (latent) -> Y <- X; the posterior of T and the counterfactual mean by enumeration."""
    graph = _graph(["x", "t", "y"], [("x", "t"), ("x", "y"), ("t", "y")])
    model = WorldModel(
        graph,
        {
            "t": BernoulliMechanism.from_coefficients([1.0], 0.2),
            "y": LinearMechanism.from_coefficients([[0.5, 2.0]], 0.0, 1.0),
        },
    )
    x0, y0, x1 = 0.3, 1.1, -1.0
    l0, l1 = x0 + 0.2, x1 + 0.2
    like = [math.exp(-0.5 * (y0 - 0.5 * x0 - 2.0 * t) ** 2) for t in (0, 1)]
    prior = [1 - sigmoid(l0), sigmoid(l0)]
    post1 = prior[1] * like[1] / (prior[0] * like[0] + prior[1] * like[1])
    obs = {"x": torch.tensor([[x0]]), "y": torch.tensor([[y0]])}
    for guide in ("grid", "importance", "normal"):
        state = infer_state(model, obs, guide=guide, num_samples=20_000, num_steps=5)
        assert state.latent == ("t",)
        assert float(state.samples["t"].mean()) == pytest.approx(post1, abs=0.02), guide
    # counterfactual: E[Y'] = sum_t p(t | x, y) sum_t' P(t' | t) (0.5 x' + 2 t') + (y - 0.5 x - 2 t)
    state = infer_state(model, obs, guide="grid", num_samples=400_000)
    cf = counterfactual(model, obs, {"x": x1}, posterior=state)
    stay1 = sigmoid(min(l0, l1)) / sigmoid(l0)
    up0 = max(0.0, sigmoid(-l0) - sigmoid(-l1)) / sigmoid(-l0)
    mean = 0.0
    for t, pt in ((0, 1 - post1), (1, post1)):
        p1 = stay1 if t == 1 else up0
        mean += pt * (0.5 * x1 + 2 * p1 + (y0 - 0.5 * x0 - 2 * t))
    assert float(cf.mean["y"]) == pytest.approx(mean, abs=0.02)


# ---------------------------------------------------------------------------- fit, do, sample
def test_fit_recovers_a_logistic_mechanism_and_root_frequencies():
    gen = torch.Generator().manual_seed(0)
    n = 20_000
    x = torch.randn(n, 1, generator=gen)
    t = (torch.rand(n, 1, generator=gen) < torch.sigmoid(2.0 * x - 0.5)).float()
    c = torch.multinomial(torch.tensor([0.2, 0.5, 0.3]), n, replacement=True, generator=gen)[:, None].float()
    graph = _graph(["x", "c", "t"], [("x", "t")])
    model = WorldModel(graph, seed=0, kind="linear", discrete={"t": 2, "c": 3})
    r = fit(
        model,
        {"x": x, "t": t, "c": c},
        schedule=FitSchedule(epochs=30, batch_size=512, lr=0.05, validation=0.1, patience=5),
    )
    assert r.losses["t"] == "cross_entropy" and r.sigma_rule["t"] == "none"
    logits = model.mechanism("t").logits(torch.tensor([[0.0], [1.0]]))
    logits = logits.detach()
    slope = float(logits[1, 1] - logits[0, 1])
    assert slope == pytest.approx(2.0, abs=0.1)
    assert float(logits[0, 1]) == pytest.approx(-0.5, abs=0.07)
    probs = model.root_priors.logits("c").exp()
    torch.testing.assert_close(probs, torch.tensor([0.2, 0.5, 0.3]), atol=0.015, rtol=0)
    draws = simulate(model, 50_000, seed=0)
    assert set(draws["c"].unique().tolist()) == {0.0, 1.0, 2.0}


def test_do_hard_values_and_callables_on_discrete_sites():
    model, beta = _mixed()
    hard = simulate(do(model, {"c": 2.0}), 1000, seed=0)
    assert bool((hard["c"] == 2).all())
    shifted = simulate(do(model, {"c": lambda c: (c + 1) % 3}), 1000, seed=0)
    natural = simulate(model, 1000, seed=0)
    assert bool((shifted["c"] == (natural["c"] + 1) % 3).all())
    torch.testing.assert_close(hard["y"].mean(), torch.tensor(beta[2]), atol=0.1, rtol=0)


def test_infer_action_through_a_bernoulli_site():
    """A -> T (logit 6 a) -> Y = 2 T + 0.1 U: reaching Y = 2 needs T = 1, i.e. a > 0."""
    graph = CausalGraph(
        [Variable("a", "action", bounds=(-1.0, 1.0)), Variable("t", "observed"), Variable("y", "observed")],
        [("a", "t"), ("t", "y")],
    )
    model = WorldModel(
        graph,
        {
            "t": BernoulliMechanism.from_coefficients([6.0], 0.0),
            "y": LinearMechanism.from_coefficients([[2.0]], 0.0, 0.1),
        },
    )
    result = infer_action(
        model,
        None,
        {"y": torch.full((4, 1), 2.0)},
        num_steps=20,
        options=ActionOptions(sampling=SamplingConfig(population=32, elites=4)),
    )
    assert bool((result.actions["a"] > 0).all())
    assert bool((result.predicted["t"] == 1).all())
