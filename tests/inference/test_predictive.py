"""A site's predictive interval with its unobserved ancestors sampled, and coverage per regime."""

import math

import pytest
import torch

from inference import coverage_by_regime, predictive_interval, predictive_intervals
from models import (
    BernoulliMechanism,
    CausalGraph,
    GatedMechanism,
    HeteroscedasticMechanism,
    LinearMechanism,
    Variable,
    WorldModel,
)

Z90 = 1.6448536
Z = {0.5: 0.6744897501960817, 0.9: 1.6448536269514722, 0.95: 1.959963984540054}


def chain():
    """X (root) -> Y = 2 X + 1 + 0.5 eps -> Z = -1.5 Y + 0.3 eps'."""
    graph = CausalGraph(
        [Variable("X", "observed"), Variable("Y", "latent"), Variable("Z", "latent")],
        [("X", "Y"), ("Y", "Z")],
    )
    mechs = {
        "Y": LinearMechanism.from_coefficients([[2.0]], 1.0, 0.5),
        "Z": LinearMechanism.from_coefficients([[-1.5]], 0.0, 0.3),
    }
    return WorldModel(graph, mechs, seed=0)


def test_the_interval_of_a_chain_end_has_the_total_variance():
    x = torch.tensor([[0.0], [1.0], [-2.0]])
    out = predictive_interval(chain(), {"X": x}, "Z", level=0.9, num_samples=40000, seed=1)
    mean = -1.5 * (2.0 * x + 1.0)
    sd = math.sqrt(1.5**2 * 0.5**2 + 0.3**2)  # the latent Y's residual passes through Z
    torch.testing.assert_close(out.mean, mean, atol=0.02, rtol=0)
    torch.testing.assert_close(out.sd, torch.full_like(mean, sd), atol=0.02 * sd, rtol=0)
    torch.testing.assert_close(out.lower, mean - Z90 * sd, atol=0.03, rtol=0)
    torch.testing.assert_close(out.upper, mean + Z90 * sd, atol=0.03, rtol=0)
    # Z given Y as well: only its own residual
    given = predictive_interval(chain(), {"X": x, "Y": 2 * x + 1}, "Z", num_samples=40000, seed=1)
    torch.testing.assert_close(given.sd, torch.full_like(mean, 0.3), atol=0.006, rtol=0)
    again = predictive_interval(chain(), {"X": x}, "Z", level=0.9, num_samples=40000, seed=1)
    assert torch.equal(again.lower, out.lower) and torch.equal(again.upper, out.upper)


def gated():
    """a -> c ~ Bernoulli(sigmoid(a - 0.5)); x | c=1 ~ N(2 b + 0.5, exp(0.3 b - 1)), x | c=0 ~ N(0, 0.05)."""
    graph = CausalGraph(
        [Variable(n, "observed") for n in ("a", "b")] + [Variable("c", "latent"), Variable("x", "latent")],
        [("a", "c"), ("b", "x"), ("c", "x")],
    )
    on = HeteroscedasticMechanism.from_coefficients(
        [[2.0, 0.0]], 0.5, log_scale_weight=[[0.3, 0.0]], log_scale_bias=-1.0
    )
    mechs = {"c": BernoulliMechanism.from_coefficients([1.0], -0.5), "x": GatedMechanism("c", on, 0.05)}
    return WorldModel(graph, mechs, seed=0)


def mixture_quantile(p_on, on, off, q):
    """The q-quantile of p_on N(on) + (1 - p_on) N(off), by bisection."""
    normal = lambda m, s, v: 0.5 * (1 + math.erf((v - m) / (s * math.sqrt(2))))  # noqa: E731
    lo, hi = -20.0, 20.0
    for _ in range(200):
        mid = (lo + hi) / 2
        cdf = p_on * normal(*on, mid) + (1 - p_on) * normal(*off, mid)
        lo, hi = (mid, hi) if cdf < q else (lo, mid)
    return (lo + hi) / 2


def test_a_gated_site_with_a_latent_switch_gives_the_mixture_quantiles():
    a = torch.tensor([[0.5], [2.0], [-1.0]])
    b = torch.tensor([[0.7], [-0.2], [1.5]])
    out = predictive_interval(gated(), {"a": a, "b": b}, "x", level=0.9, num_samples=40000, seed=2)
    for i in range(3):
        p_on = 1 / (1 + math.exp(-(float(a[i]) - 0.5)))
        on = (2 * float(b[i]) + 0.5, math.exp(0.3 * float(b[i]) - 1.0))
        off = (0.0, 0.05)
        for q, got in ((0.05, out.lower[i, 0]), (0.95, out.upper[i, 0])):
            assert float(got) == pytest.approx(mixture_quantile(p_on, on, off, q), abs=0.03), (i, q)
        assert float(out.mean[i, 0]) == pytest.approx(p_on * on[0], abs=0.02)
    # the switch observed: the on branch alone
    on_only = predictive_interval(
        gated(), {"a": a, "b": b, "c": torch.ones(3, 1)}, "x", num_samples=40000, seed=2
    )
    torch.testing.assert_close(on_only.sd, torch.exp(0.3 * b - 1.0), atol=0.01, rtol=0)


def test_coverage_is_counted_per_regime():
    g = torch.Generator().manual_seed(0)
    n = 20000
    regime = (torch.rand(n, generator=g) < 0.15).long()
    truth = torch.randn(n, 1, generator=g)
    half = torch.where(regime[:, None] == 1, torch.full((n, 1), 0.5), torch.full((n, 1), Z90))
    out = coverage_by_regime(truth, -half, half, regime, names={0: "no contact", 1: "contact"})
    assert out["no contact"]["coverage"] == pytest.approx(0.90, abs=0.01)
    assert out["contact"]["coverage"] == pytest.approx(math.erf(0.5 / math.sqrt(2)), abs=0.025)
    assert out["contact"]["rows"] + out["no contact"]["rows"] == out["all"]["rows"] == n


def test_bad_inputs():
    x = torch.zeros(2, 1)
    with pytest.raises(ValueError, match="level must be a number in \\(0, 1\\), got 1.5"):
        predictive_interval(chain(), {"X": x}, "Z", level=1.5)
    with pytest.raises(ValueError, match="num_samples must be an int >= 2, got 1"):
        predictive_interval(chain(), {"X": x}, "Z", num_samples=1)
    with pytest.raises(ValueError, match="site 'W' is not in the model"):
        predictive_interval(chain(), {"X": x}, "W")
    with pytest.raises(ValueError, match="site 'X' is given in values"):
        predictive_interval(chain(), {"X": x}, "X")
    with pytest.raises(ValueError, match="must have the same rows"):
        coverage_by_regime(torch.zeros(3, 1), torch.zeros(3, 1), torch.zeros(2, 1), torch.zeros(3))
    with pytest.raises(ValueError, match="must not hold NaN"):
        coverage_by_regime(torch.full((1, 1), math.nan), torch.zeros(1, 1), torch.zeros(1, 1), torch.zeros(1))


def test_intervals_at_several_levels_share_one_set_of_draws_and_match_the_closed_form():
    x = torch.tensor([[0.0], [1.0]])
    levels = (0.5, 0.9, 0.95)
    many = predictive_intervals(chain(), {"X": x}, "Z", levels, num_samples=8000, seed=3)
    sd = math.sqrt(1.5**2 * 0.5**2 + 0.3**2)
    for level, interval in zip(levels, many, strict=True):
        one = predictive_interval(chain(), {"X": x}, "Z", level=level, num_samples=8000, seed=3)
        torch.testing.assert_close(interval.lower, one.lower, atol=0, rtol=0)  # the same draws
        torch.testing.assert_close(interval.upper, one.upper, atol=0, rtol=0)
        half = (interval.upper - interval.lower) / 2
        torch.testing.assert_close(half, torch.full_like(half, Z[level] * sd), atol=0.04, rtol=0)
    with pytest.raises(ValueError, match="levels is empty"):
        predictive_intervals(chain(), {"X": x}, "Z", ())
    with pytest.raises(ValueError, match="level must be a number in"):
        predictive_intervals(chain(), {"X": x}, "Z", (0.5, 1.0))
