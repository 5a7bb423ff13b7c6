"""iCEM's parts: the coloured-noise spectrum, kept elites, the shifted warm start and a quantile risk."""

import math

import numpy as np
import pytest
import torch

from inference import ActionOptions, SamplingConfig, infer_action
from inference.action_objective import ActionObjective, check_risk, gaussian_log_preference
from inference.planning import colored_noise, cross_entropy_search, shift_plan
from models import CausalGraph, FunctionMechanism, Variable, WorldModel
from models.ensemble import EnsembleMechanism


@pytest.mark.parametrize("beta", [0.0, 1.0, 2.0, 3.0])
def test_colored_noise_spectrum_has_slope_minus_beta(beta):
    """The mean periodogram of the samples falls as f^-beta: log-log slope within 0.1 of -beta."""
    h = 64
    x = colored_noise((3000, h), beta, torch.Generator().manual_seed(5), torch.float64)
    power = torch.fft.rfft(x, dim=-1).abs().pow(2).mean(0)[1:]  # f = 1/H .. 1/2
    freqs = torch.fft.rfftfreq(h, dtype=torch.float64)[1:]
    slope = np.polyfit(np.log(freqs.numpy()), np.log(power.numpy()), 1)[0]
    assert abs(slope + beta) < 0.1


def test_population_sizes_decay_to_twice_the_elites():
    cfg = SamplingConfig(population=100, elites=20, iterations=6, population_decay=2.0, keep_elites=0.3)
    assert cfg.sizes() == (100, 50, 40, 40, 40, 40)  # floor min(2E, P) = 40
    assert cfg.kept == 6  # ceil(0.3 * 20)
    plain = SamplingConfig(
        population=50, elites=5, iterations=3, noise_beta=0.0, keep_elites=0.0, population_decay=1.0
    )
    assert plain.sizes() == (50, 50, 50) and plain.kept == 0


@pytest.mark.parametrize("keep", [0.0, 0.5, 1.0])
def test_kept_elites_enter_the_next_refit(keep):
    """alpha = 0: the mean of iteration 3 (its first candidate) is the mean of E_2, the best E of
    iteration 2's fresh candidates and the ceil(xi E) best elites of iteration 1."""
    e, n, h, d = 4, 1, 3, 2
    calls = []
    target = torch.tensor([0.3, -0.2])

    def objective(a):
        calls.append(a.clone())
        return (a - target).pow(2).sum((-1, -2))

    cfg = SamplingConfig(
        population=12, elites=e, iterations=3, alpha=0.0, keep_elites=keep, population_decay=1.0
    )
    big = 10 * torch.ones(d)
    cross_entropy_search(objective, torch.zeros(n, h, d), -big, big, cfg, torch.Generator().manual_seed(6))
    l1, l2 = objective(calls[0]), objective(calls[1])
    k = math.ceil(keep * e)
    kept = calls[0][l1[:, 0].argsort()[:k]]
    pool = torch.cat([calls[1], kept])
    pool_loss = torch.cat([l2[:, 0], l1[l1[:, 0].argsort()[:k], 0]])
    expected = pool[pool_loss.argsort()[:e]].mean(0)
    torch.testing.assert_close(calls[2][0], expected, atol=1e-6, rtol=0)


def test_search_result_is_the_best_seen_and_never_rises():
    torch.manual_seed(0)
    target = torch.tensor([0.5])

    def objective(a):
        return (a - target).abs().sum((-1, -2))

    cfg = SamplingConfig(population=16, elites=4, iterations=5, keep_elites=0.0)
    found = cross_entropy_search(
        objective, torch.zeros(2, 4, 1), -torch.ones(1), torch.ones(1), cfg, torch.Generator().manual_seed(7)
    )
    assert list(found.history) == sorted(found.history, reverse=True)
    torch.testing.assert_close(objective(found.elites), found.losses, atol=1e-6, rtol=0)
    assert bool((found.losses[1:] >= found.losses[:-1]).all())


def test_shift_plan_moves_the_sequence_one_step():
    seq = torch.arange(12.0).reshape(2, 3, 2)
    out = shift_plan(seq)
    torch.testing.assert_close(out[:, :2], seq[:, 1:])
    torch.testing.assert_close(out[:, 2], seq[:, 2])
    filled = shift_plan(seq, torch.tensor([-1.0, 1.0]))
    torch.testing.assert_close(filled[:, 2], torch.tensor([[-1.0, 1.0], [-1.0, 1.0]]))
    with pytest.raises(ValueError, match=r"sequence has shape \(3,\), expected \(\.\.\., H, D\)"):
        shift_plan(torch.zeros(3))
    with pytest.raises(ValueError, match=r"fill has shape \(3,\), expected \(2,\)"):
        shift_plan(seq, torch.zeros(3))


def test_shifted_warm_start_keeps_the_remaining_plan():
    """Tracking a moving reference: the shifted optimum of step t is optimal for step t + 1 but its last step."""
    ref = torch.linspace(-0.8, 0.8, 9)[:, None]

    def objective_at(t):
        return lambda a: (a - ref[t : t + 4]).pow(2).sum((-1, -2))

    cfg = SamplingConfig(population=8, elites=2, iterations=1)
    low, high = -torch.ones(1), torch.ones(1)
    plan0 = ref[0:4][None]
    warm = cross_entropy_search(
        objective_at(1), shift_plan(plan0), low, high, cfg, torch.Generator().manual_seed(8)
    )
    cold = cross_entropy_search(
        objective_at(1), torch.zeros(1, 4, 1), low, high, cfg, torch.Generator().manual_seed(8)
    )
    step = float(ref[4] - ref[3]) ** 2  # only the repeated last step is off
    assert float(warm.losses[0, 0]) <= step + 1e-6 < float(cold.losses[0, 0])


def _three_members():
    g = CausalGraph(
        [
            Variable("a", "action", bounds=(-1.0, 1.0)),
            Variable("q_prev", "observed", lag=1, lag_of="q"),
            Variable("q", "latent"),
        ],
        [("a", "q"), ("q_prev", "q")],
    )
    members = [
        FunctionMechanism(lambda z, c=c: z[..., 1:2] + c * z[..., 0:1], 2, 1, sigma=0.1)
        for c in (0.5, 1.0, 2.0)
    ]
    return WorldModel(g, {"q": EnsembleMechanism(members)})


def test_quantile_risk_matches_the_hand_computed_case():
    """Members q = c_k a, c = (0.5, 1, 2), a = 0.4, target 0.6, scale 1: losses 0.5 (c_k a - 0.6)^2 =
    (0.08, 0.02, 0.02); sorted (0.02, 0.02, 0.08), Q_0.75 at position 1.5: 0.02 + 0.5 (0.08 - 0.02) = 0.05."""
    model = _three_members()
    objective = ActionObjective(
        model,
        {"q_prev": torch.zeros(1, 1)},
        ["a"],
        {},
        gaussian_log_preference({"q": torch.tensor([[0.6]])}, 1.0),
        1,
        1,
        "final",
        check_risk(("quantile", 0.75)),
        {"q": 1.0},
    )
    loss = objective(torch.full((1, 1, 1, 1), 0.4))
    torch.testing.assert_close(loss, torch.tensor([[0.05]]), atol=1e-6, rtol=0)
    median = ActionObjective(
        model,
        {"q_prev": torch.zeros(1, 1)},
        ["a"],
        {},
        gaussian_log_preference({"q": torch.tensor([[0.6]])}, 1.0),
        1,
        1,
        "final",
        check_risk(("quantile", 0.5)),
        {"q": 1.0},
    )
    torch.testing.assert_close(
        median(torch.full((1, 1, 1, 1), 0.4)), torch.tensor([[0.02]]), atol=1e-6, rtol=0
    )


def test_quantile_risk_plans_cautiously():
    """The worst member (q = 1) of c = (0.5, 1, 2) towards d = 0.5: min_a max_k |c_k a - d| balances
    the extreme members, d - 0.5 a = 2 a - d, so a = 2 d / 2.5 = 0.4 (the mean model would give 0.5 / 1.17)."""
    model = _three_members()
    r = infer_action(
        model,
        {"q_prev": torch.zeros(1, 1)},
        {"q": torch.tensor([[0.5]])},
        options=ActionOptions(
            risk=("quantile", 1.0),
            sampling=SamplingConfig(population=64, elites=8, refine_steps=0, iterations=6),
        ),
        num_steps=1,
    )
    assert abs(float(r.actions["a"][0, 0]) - 0.4) < 0.02


@pytest.mark.parametrize(
    ("risk", "match"),
    [
        (("quantile", 1.5), "risk quantile q must be >= 0 and <= 1 \\(a finite number\\), got 1.5"),
        (("quantile", -0.1), "risk quantile q must be >= 0 and <= 1 \\(a finite number\\), got -0.1"),
        (("median", 0.5), "risk must be None, 'mean', \\('disagreement', weight\\) or \\('quantile', q\\)"),
    ],
)
def test_bad_quantile_risk_is_refused(risk, match):
    with pytest.raises(ValueError, match=match):
        check_risk(risk)


@pytest.mark.parametrize("horizon", [0, -2])
def test_a_horizon_below_one_is_refused(horizon):
    with pytest.raises(ValueError, match=f"horizon must be a positive int, got {horizon}"):
        infer_action(
            _three_members(),
            {"q_prev": torch.zeros(1, 1)},
            {"q": torch.zeros(1, 1)},
            options=ActionOptions(horizon=horizon),
        )


def test_a_negative_noise_exponent_is_refused():
    with pytest.raises(ValueError, match="noise_beta must be >= 0 \\(a finite number\\), got -0.5"):
        SamplingConfig(noise_beta=-0.5)
