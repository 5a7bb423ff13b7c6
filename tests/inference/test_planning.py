"""The sampling stage (CEM / iCEM) and the epistemic-risk objective of action inference."""

import pytest
import torch

from inference import ActionOptions, SamplingConfig, infer_action
from inference.action_objective import ActionObjective, check_risk, gaussian_log_preference
from inference.planning import colored_noise, cross_entropy_search
from models import CausalGraph, FunctionMechanism, Variable, WorldModel, finger_graph
from models.ensemble import EnsembleMechanism

FAST = SamplingConfig(population=64, elites=8, iterations=3, refine_steps=150)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"population": 8, "elites": 16}, "population 8 is smaller than elites 16"),
        ({"population": 0}, "population must be a positive int, got 0"),
        ({"elites": 0}, "elites must be a positive int, got 0"),
        ({"iterations": 0}, "iterations must be a positive int, got 0"),
        ({"alpha": 1.0}, "alpha must be >= 0 and < 1 \\(a finite number\\), got 1"),
        ({"alpha": -0.1}, "alpha must be >= 0 and < 1 \\(a finite number\\), got -0.1"),
        ({"noise_beta": -1.0}, "noise_beta must be >= 0 \\(a finite number\\), got -1"),
        ({"init_std": 0.0}, "init_std must be > 0 \\(a finite number\\), got 0"),
        ({"refine_steps": -1}, "refine_steps must be a non-negative int, got -1"),
        ({"refine_elites": 17}, "refine_elites 17 is larger than elites 16"),
        ({"keep_elites": 1.5}, "keep_elites must be >= 0 and <= 1 \\(a finite number\\), got 1.5"),
        ({"keep_elites": -0.1}, "keep_elites must be >= 0 and <= 1 \\(a finite number\\), got -0.1"),
        ({"population_decay": 0.9}, "population_decay must be >= 1 \\(a finite number\\), got 0.9"),
        ({"population": 64.0}, "population must be a positive int, got 64.0"),
    ],
)
def test_sampling_config_refuses_bad_sizes(kwargs, match):
    with pytest.raises(ValueError, match=match):
        SamplingConfig(**kwargs)


def test_white_noise_is_randn():
    a = colored_noise((3, 5, 1), 0.0, torch.Generator().manual_seed(0), torch.float32)
    b = torch.randn((3, 5, 1), generator=torch.Generator().manual_seed(0))
    assert torch.equal(a, b)


@pytest.mark.parametrize(("beta", "low", "high"), [(0.0, -0.05, 0.05), (1.0, 0.3, 0.8), (2.0, 0.8, 1.0)])
def test_colored_noise_has_unit_variance_and_correlates_over_the_horizon(beta, low, high):
    x = colored_noise((4000, 32), beta, torch.Generator().manual_seed(1), torch.float64)
    assert x.shape == (4000, 32) and x.dtype == torch.float64
    assert abs(float(x.var()) - 1.0) < 0.1
    lag1 = float((x[:, 1:] * x[:, :-1]).mean() / x.var())
    assert low < lag1 < high


def test_cem_is_batched_over_units_and_keeps_its_best():
    """L(a) = |a - c_n|^2 per unit; the start (the mean) is a member of the first population."""
    n, h, d = 5, 2, 3
    centre = torch.rand(n, h, d, generator=torch.Generator().manual_seed(2)) * 2 - 1
    calls = []

    def objective(a):
        calls.append(tuple(a.shape))
        return (a - centre).pow(2).sum((-1, -2))

    low, high = -torch.ones(d), torch.ones(d)
    cfg = SamplingConfig(population=128, elites=8, iterations=4)
    found = cross_entropy_search(
        objective, torch.zeros(n, h, d), low, high, cfg, torch.Generator().manual_seed(3)
    )
    # one call per iteration for all units x candidates; iCEM's population decays by 1.25
    assert calls == [(p, n, h, d) for p in (128, 103, 82, 66)] == [(p, n, h, d) for p in cfg.sizes()]
    assert found.elites.shape == (8, n, h, d) and found.losses.shape == (8, n)
    assert bool((found.losses[1:] >= found.losses[:-1]).all())
    assert list(found.history) == sorted(found.history, reverse=True)
    assert found.history[-1] < 0.1
    at_start = cross_entropy_search(objective, centre, low, high, cfg, torch.Generator().manual_seed(3))
    assert float(at_start.losses[0].abs().max()) == 0.0


# ---------------------------------------------------------------- epistemic risk


def _ensemble_joint(gains=(0.5, 1.5)):
    """Members q = q_prev + c_k a; the site is their moment-matched Normal (loc q_prev + mean(c) a)."""
    g = CausalGraph(
        [
            Variable("a", "action", bounds=(-1.0, 1.0)),
            Variable("q_prev", "observed", lag=1, lag_of="q"),
            Variable("q", "latent"),
        ],
        [("a", "q"), ("q_prev", "q")],
    )
    members = [
        FunctionMechanism(lambda z, c=c: z[..., 1:2] + c * z[..., 0:1], 2, 1, sigma=0.1) for c in gains
    ]
    return WorldModel(g, {"q": EnsembleMechanism(members)})


@pytest.mark.parametrize(
    ("risk", "factor"),
    [
        (None, 1.0),  # the mean member: a = d
        ("mean", 0.8),  # argmin mean_k (c_k a - d)^2 = d mean(c) / mean(c^2) = d / 1.25
        (("disagreement", 0.5), 0.8),
        (("disagreement", 2.0), 0.5),
        (("disagreement", -0.5), 1 / 0.75),  # a bonus for disagreement: bolder actions
    ],
)
@pytest.mark.parametrize("sampling", [None, FAST])
def test_risk_gives_the_closed_form_action(risk, factor, sampling):
    """L = 0.5 (a - d)^2 + w Var_k(c_k a) = 0.5 (a - d)^2 + 0.25 w a^2, so a* = d / (1 + 0.5 w)."""
    model = _ensemble_joint()
    q_prev = torch.tensor([[0.0], [0.3], [-0.2], [1.0]])
    d = torch.tensor([[0.5], [-0.6], [0.2], [-0.3]])
    r = infer_action(
        model,
        {"q_prev": q_prev},
        {"q": q_prev + d},
        options=ActionOptions(risk=risk, sampling=sampling),
        num_steps=300,
    )
    torch.testing.assert_close(r.actions["a"], factor * d, atol=2e-3, rtol=0)
    torch.testing.assert_close(r.predicted["q"], q_prev + factor * d, atol=2e-3, rtol=0)


def test_mean_risk_equals_half_weight_disagreement_for_the_gaussian_preference():
    """E_k[0.5 |x_k - t|^2 / s^2] = 0.5 |mean_k x_k - t|^2 / s^2 + 0.5 sum Var_k / s^2, on an MLP ensemble."""
    model = WorldModel(finger_graph("state"), seed=0, members=4)
    n = 6
    q_prev = torch.linspace(-2.0, 0.3, n)[:, None]
    target = {"q.finger": torch.linspace(0.2, -1.0, n)[:, None]}
    pref = gaussian_log_preference(target, 0.3)
    a = torch.rand(7, n, 1, 1, generator=torch.Generator().manual_seed(4)) * 1.33 - 1.0
    losses = {}
    for risk in ("mean", ("disagreement", 0.5), ("disagreement", 0.0)):
        objective = ActionObjective(
            model,
            {"q_prev.finger": q_prev},
            ["act.finger"],
            {},
            pref,
            n,
            1,
            "final",
            check_risk(risk),
            {"q.finger": 0.3},
        )
        losses[str(risk)] = objective(a)
    torch.testing.assert_close(losses["mean"], losses["('disagreement', 0.5)"], rtol=1e-5, atol=1e-6)
    assert bool((losses["mean"] > losses["('disagreement', 0.0)"]).all())  # the members disagree


def test_risk_over_a_horizon_uses_the_members_rollouts():
    """Integrator members q(t) = q(t-1) + c_k a(t): final-step mean risk puts sum_t a_t = 0.8 d."""
    model = _ensemble_joint()
    q0 = torch.zeros(2, 1)
    d = torch.tensor([[1.2], [-0.9]])
    r = infer_action(
        model,
        {"q_prev": q0},
        {"q": d},
        options=ActionOptions(horizon=3, risk="mean", sampling=FAST),
        num_steps=300,
    )
    torch.testing.assert_close(r.actions["a"].sum(1), 0.8 * d, atol=3e-3, rtol=0)
    assert r.predicted["q"].shape == (2, 3, 1)
