import dataclasses
import random

import numpy as np
import pytest
import torch

from inference import ActionOptions, Intervene, ReplayNoise, SamplingConfig, infer_action
from models import CausalGraph, FunctionMechanism, Variable, WorldModel, finger_graph

FAST = SamplingConfig(population=64, elites=8, iterations=3, refine_steps=100)


def _joint_graph():
    return CausalGraph(
        [
            Variable("a", "action", bounds=(-1.0, 1.0)),
            Variable("q_prev", "observed", lag=1, lag_of="q"),
            Variable("q", "latent"),
        ],
        [("a", "q"), ("q_prev", "q")],
    )


def _function_model(fn, sigma=0.1):
    return WorldModel(_joint_graph(), {"q": FunctionMechanism(fn, 2, 1, sigma=sigma)})


@pytest.fixture
def plant():
    """q = q_prev + tanh(2 a), a in [-1, 1]: invertible in a for any q_prev."""
    return _function_model(lambda z: z[..., 1:2] + torch.tanh(2 * z[..., 0:1]))


def reachable_targets(n, seed):
    g = torch.Generator().manual_seed(seed)
    q_prev = torch.randn(n, 1, generator=g)
    a_true = torch.rand(n, 1, generator=g) * 1.6 - 0.8
    return q_prev, q_prev + torch.tanh(2 * a_true), a_true


def test_reaches_95_percent_of_128_targets(plant):
    q_prev, target, a_true = reachable_targets(128, 0)
    r = infer_action(plant, {"q_prev": q_prev}, {"q": target}, num_steps=200, options=ActionOptions(lr=0.05))
    err = (r.predicted["q"] - target).abs()
    assert float((err < 0.05).float().mean()) >= 0.95
    assert r.actions["a"].shape == (128, 1)
    assert len(r.loss) == 200 and r.loss[-1] < r.loss[0]
    assert r.final_loss.shape == (128,)
    torch.testing.assert_close(r.actions["a"], a_true, atol=0.05, rtol=0)


def test_actions_stay_within_bounds_for_unreachable_targets(plant):
    q_prev = torch.zeros(4, 1)
    r = infer_action(
        plant,
        {"q_prev": q_prev},
        {"q": torch.tensor([[5.0], [-5.0], [5.0], [-5.0]])},
        num_steps=100,
        options=ActionOptions(lr=0.2),
    )
    torch.testing.assert_close(r.actions["a"].ravel(), torch.tensor([1.0, -1.0, 1.0, -1.0]))


def test_units_are_independent(plant):
    q_prev, target, _ = reachable_targets(8, 1)
    both = infer_action(plant, {"q_prev": q_prev}, {"q": target})
    first = infer_action(plant, {"q_prev": q_prev[:1]}, {"q": target[:1]})
    torch.testing.assert_close(both.actions["a"][:1], first.actions["a"])


def test_inits_and_custom_preference(plant):
    q_prev, target, _ = reachable_targets(16, 2)
    r = infer_action(plant, {"q_prev": q_prev}, {"q": target}, options=ActionOptions(init="random"), seed=3)
    r2 = infer_action(plant, {"q_prev": q_prev}, {"q": target}, options=ActionOptions(init="random"), seed=3)
    torch.testing.assert_close(r.actions["a"], r2.actions["a"])
    r3 = infer_action(
        plant,
        {"q_prev": q_prev},
        {"q": target},
        options=ActionOptions(init={"a": torch.zeros(16, 1)}, lr=1e-9),
        num_steps=1,
    )
    assert torch.all(r3.actions["a"].abs() < 1e-6)

    def prefer_high(pred):
        return pred["q"][:, 0]

    r4 = infer_action(
        plant, {"q_prev": q_prev}, options=ActionOptions(log_preference=prefer_high, lr=0.1), num_steps=100
    )
    assert torch.all(r4.actions["a"] == 1.0)


def test_finger_preset_runs_batched():
    m = WorldModel(finger_graph("state"))
    r = infer_action(m, {"q_prev.finger": torch.zeros(5, 1)}, {"q.finger": torch.zeros(5, 1)}, num_steps=3)
    assert set(r.actions) == {"act.finger"}
    lo, hi = -1.0, 0.33
    assert torch.all((r.actions["act.finger"] >= lo) & (r.actions["act.finger"] <= hi))


def test_model_parameters_are_left_untouched(plant):
    m = WorldModel(finger_graph("thesis"))
    before = {k: v.clone() for k, v in m.state_dict().items()}
    infer_action(m, {"q_prev.finger": torch.zeros(3, 1)}, {"q.finger": torch.ones(3, 1)}, num_steps=10)
    for k, v in m.state_dict().items():
        assert torch.equal(v, before[k]), k
    assert all(p.requires_grad for p in m.parameters())


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"targets": {"w": torch.zeros(2, 1)}}, "unknown variable in targets 'w'"),
        ({"targets": {"q": torch.zeros(3, 1)}}, "has 3 rows, expected 2"),
        ({"targets": {"q": torch.zeros(2, 2)}}, "expected \\(N, 1\\)"),
        ({"targets": {"q": torch.full((2, 1), np.nan)}}, "NaN or inf"),
        ({"targets": {"a": torch.zeros(2, 1)}}, "target 'a' is an optimised action"),
        ({"targets": None}, "give targets or a log_preference"),
        ({"actions": ["q"]}, "only actions can be optimised"),
        ({"options": ActionOptions(init="zero")}, "init 'zero' unknown"),
        ({"options": ActionOptions(init={"a": torch.full((2, 1), 3.0)})}, "outside the bounds"),
        ({"num_steps": 0}, "num_steps must be a positive int"),
    ],
)
def test_bad_input(plant, kwargs, match):
    args = {"targets": {"q": torch.zeros(2, 1)}, **kwargs}
    with pytest.raises(ValueError, match=match):
        infer_action(plant, {"q_prev": torch.zeros(2, 1)}, **args)


# ---------------------------------------------------------------- the thesis protocol stays


GOLDEN_INPUT = (torch.tensor([[0.0], [0.5], [-1.0], [2.0]]), torch.tensor([[0.3], [1.2], [-1.9], [5.0]]))

# The Alg. 4.2 results (float32, exact) of the implementation before the sampling stage existed.
GOLDEN = {
    "midpoint": (
        {"num_steps": 50, "options": ActionOptions(lr=0.05)},
        ["0x1.4d95d2p-3", "0x1.cb061ep-2", "-0x1.aaa4bap-1", "0x1p+0"],
        ["0x1.c5e98ap-14", "0x1.bf4f08p-14", "0x1.fb041ep-12", "0x1.094abp+1"],
        "0x1.09673cp-1",
    ),
    "random": (
        {"num_steps": 30, "options": ActionOptions(lr=0.1, init="random", scale=0.5), "seed": 3},
        ["0x1.bf8d5ap-3", "0x1p+0", "-0x1.bac53p-1", "0x1p+0"],
        ["0x1.953d5ap-6", "0x1.1d88d4p-3", "0x1.8ed438p-9", "0x1.094abp+3"],
        "0x1.0ffa5ap+1",
    ),
}


@pytest.mark.parametrize("case", list(GOLDEN))
def test_without_sampling_the_result_is_bit_for_bit_the_thesis_protocol(plant, case):
    kwargs, actions, final, last = GOLDEN[case]
    q_prev, target = GOLDEN_INPUT
    r = infer_action(plant, {"q_prev": q_prev}, {"q": target}, **kwargs)
    expected = torch.tensor([[float.fromhex(x)] for x in actions])
    assert torch.equal(r.actions["a"], expected)
    assert torch.equal(r.final_loss, torch.tensor([float.fromhex(x) for x in final]))
    assert r.loss[-1] == float.fromhex(last)
    assert r.search_loss == ()
    options = dataclasses.replace(kwargs["options"], sampling=None, horizon=1, risk=None)
    explicit = infer_action(plant, {"q_prev": q_prev}, {"q": target}, **{**kwargs, "options": options})
    assert torch.equal(explicit.actions["a"], expected)


# ---------------------------------------------------------------- closed forms


def _limited_targets(n, seed):
    """q = clip(q_prev + 2a - 1, -0.5, 1): the midpoint a = 0 sits on the lower joint limit."""
    g = torch.Generator().manual_seed(seed)
    q_prev = torch.rand(n, 1, generator=g) * 0.6 - 0.3
    target = torch.rand(n, 1, generator=g) - 0.4
    return q_prev, target, (target + 1 - q_prev) / 2


def test_sampling_escapes_the_joint_limit_plateau_where_adam_stalls():
    model = _function_model(lambda z: torch.clamp(z[..., 1:2] + 2 * z[..., 0:1] - 1, -0.5, 1.0))
    q_prev, target, a_true = _limited_targets(64, 0)
    stalled = infer_action(model, {"q_prev": q_prev}, {"q": target})
    assert torch.equal(stalled.actions["a"], torch.zeros(64, 1))  # zero gradient: Adam never moves
    assert float((stalled.predicted["q"] - target).abs().min()) > 0.09
    r = infer_action(model, {"q_prev": q_prev}, {"q": target}, options=ActionOptions(sampling=FAST))
    assert float((r.predicted["q"] - target).abs().max()) < 1e-3
    torch.testing.assert_close(r.actions["a"], a_true, atol=1e-3, rtol=0)
    assert len(r.search_loss) == 3 and list(r.search_loss) == sorted(r.search_loss, reverse=True)
    assert len(r.loss) == 100 and r.final_loss.shape == (64,)
    assert float(r.final_loss.mean()) <= r.search_loss[-1]


def test_sampling_escapes_a_tanh_plateau_towards_the_midpoint():
    """q = q_prev + tanh(20 (a - 0.6)): saturated (zero float32 gradient) at the midpoint."""
    model = _function_model(lambda z: z[..., 1:2] + torch.tanh(20 * (z[..., 0:1] - 0.6)))
    g = torch.Generator().manual_seed(1)
    q_prev = torch.zeros(32, 1)
    a_true = 0.5 + 0.2 * torch.rand(32, 1, generator=g)
    target = torch.tanh(20 * (a_true - 0.6))
    stalled = infer_action(model, {"q_prev": q_prev}, {"q": target})
    assert torch.equal(stalled.actions["a"], torch.zeros(32, 1))
    sampling = dataclasses.replace(FAST, refine_steps=150)  # slope 20: small Adam steps, more of them
    r = infer_action(
        model, {"q_prev": q_prev}, {"q": target}, options=ActionOptions(sampling=sampling, lr=0.01)
    )
    assert float((r.predicted["q"] - target).abs().max()) < 1e-3
    torch.testing.assert_close(r.actions["a"], a_true, atol=1e-3, rtol=0)


@pytest.mark.parametrize("sampling", [None, FAST])
def test_linear_model_gives_the_analytic_action(sampling):
    """q = q_prev + 0.5 a + 0.1 u: a* = 2 (target - q_prev - 0.1 u), also with abducted u replayed."""
    model = _function_model(lambda z: z[..., 1:2] + 0.5 * z[..., 0:1])
    g = torch.Generator().manual_seed(2)
    q_prev = torch.randn(32, 1, generator=g)
    u = torch.randn(32, 1, generator=g)
    a_true = torch.rand(32, 1, generator=g) * 1.6 - 0.8
    target = q_prev + 0.5 * a_true + 0.1 * u
    abducted = ReplayNoise({"q": u}, default="expected")(model)
    for program, expected in ((model, a_true + 0.2 * u), (abducted, a_true)):
        r = infer_action(
            program,
            {"q_prev": q_prev},
            {"q": target},
            options=ActionOptions(sampling=sampling),
            num_steps=300,
        )
        torch.testing.assert_close(r.actions["a"], expected.clamp(-1, 1), atol=1e-3, rtol=0)


def test_sampled_plan_matches_the_program_under_do():
    model = WorldModel(finger_graph("state"), seed=0)
    q_prev = torch.linspace(-2.5, 0.4, 16)[:, None]
    target = torch.linspace(0.3, -2.0, 16)[:, None]
    r = infer_action(
        model, {"q_prev.finger": q_prev}, {"q.finger": target}, options=ActionOptions(sampling=FAST), seed=4
    )
    a = r.actions["act.finger"]
    assert bool(((a >= -1.0) & (a <= 0.33)).all())
    program = Intervene({"act.finger": a})(ReplayNoise({}, default="expected")(model))
    out = program({"q_prev.finger": q_prev}, 16)
    torch.testing.assert_close(r.predicted["q.finger"], out["q.finger"], atol=1e-6, rtol=0)
    loss = 0.5 * (out["q.finger"] - target).pow(2).sum(-1)
    torch.testing.assert_close(r.final_loss, loss, atol=1e-6, rtol=0)
    again = infer_action(
        model, {"q_prev.finger": q_prev}, {"q.finger": target}, options=ActionOptions(sampling=FAST), seed=4
    )
    assert torch.equal(again.actions["act.finger"], a)


def test_sampling_never_loses_the_thesis_start(plant):
    """With one iteration, no refinement and a tiny population the midpoint (a member) bounds the loss."""
    q_prev, target, _ = reachable_targets(16, 5)
    start = infer_action(
        plant, {"q_prev": q_prev}, {"q": target}, num_steps=1, options=ActionOptions(lr=1e-12)
    )
    cfg = SamplingConfig(population=2, elites=1, iterations=1, refine_steps=0)
    r = infer_action(plant, {"q_prev": q_prev}, {"q": target}, options=ActionOptions(sampling=cfg))
    assert r.loss == () and len(r.search_loss) == 1
    assert bool((r.final_loss <= start.final_loss + 1e-6).all())


def test_custom_preference_broadcasts_over_candidates(plant):
    q_prev = torch.zeros(4, 1)
    r = infer_action(
        plant,
        {"q_prev": q_prev},
        options=ActionOptions(log_preference=lambda p: p["q"][..., 0], sampling=FAST),
    )
    torch.testing.assert_close(r.actions["a"], torch.ones(4, 1))
    with pytest.raises(ValueError, match=r"log_preference returned \(4,\), expected shape \(64, 4\)"):
        infer_action(
            plant,
            {"q_prev": q_prev},
            options=ActionOptions(log_preference=lambda p: p["q"][0, :, 0], sampling=FAST),
        )


def test_several_and_fixed_actions():
    g = CausalGraph(
        [
            Variable("a", "action", dim=2, bounds=([-1.0, 0.0], [1.0, 2.0])),
            Variable("b", "action", bounds=(-1.0, 1.0)),
            Variable("y", "latent"),
        ],
        [("a", "y"), ("b", "y")],
    )
    model = WorldModel(
        g, {"y": FunctionMechanism(lambda z: z[..., 0:1] - z[..., 1:2] + 0.5 * z[..., 2:3], 3, 1)}
    )
    target = torch.tensor([[-2.5], [1.5]])
    r = infer_action(model, None, {"y": target}, options=ActionOptions(sampling=FAST))
    assert r.actions["a"].shape == (2, 2) and r.actions["b"].shape == (2, 1)
    torch.testing.assert_close(r.predicted["y"], target, atol=1e-3, rtol=0)
    fixed = infer_action(model, {"b": torch.ones(2, 1)}, {"y": target}, options=ActionOptions(sampling=FAST))
    assert set(fixed.actions) == {"a"}
    torch.testing.assert_close(fixed.predicted["y"], target, atol=1e-3, rtol=0)


# ---------------------------------------------------------------- horizons


def _integrator():
    """q(t) = q(t-1) + 0.5 a(t), rolled forward by Alg. 4.1."""
    return _function_model(lambda z: z[..., 1:2] + 0.5 * z[..., 0:1])


@pytest.mark.parametrize("sampling", [None, FAST])
def test_horizon_every_step_reaches_the_target_at_once(sampling):
    """Scoring every step: the optimum is a_1 = 2 (target - q_0), then a_2 = a_3 = 0."""
    model = _integrator()
    q0 = torch.tensor([[0.0], [0.2], [-0.3]])
    target = torch.tensor([[0.4], [-0.2], [0.1]])
    r = infer_action(
        model,
        {"q_prev": q0},
        {"q": target},
        options=ActionOptions(horizon=3, target_at="every", sampling=sampling),
        num_steps=400,
    )
    a = r.actions["a"]
    assert a.shape == (3, 3, 1) and r.predicted["q"].shape == (3, 3, 1)
    expected = torch.cat([2 * (target - q0), torch.zeros(3, 1), torch.zeros(3, 1)], 1)[..., None]
    torch.testing.assert_close(a, expected, atol=2e-3, rtol=0)
    rolled = model.rollout({"q_prev": q0}, {"a": a})
    torch.testing.assert_close(r.predicted["q"], rolled["q"])


def test_horizon_final_step_needs_several_steps():
    """A target 1.2 away needs > 2 steps of at most 0.5 each: only the final step is scored."""
    model = _integrator()
    q0 = torch.zeros(2, 1)
    target = torch.tensor([[1.2], [-1.2]])
    r = infer_action(
        model,
        {"q_prev": q0},
        {"q": target},
        options=ActionOptions(horizon=3, sampling=SamplingConfig(noise_beta=2.0)),
    )
    torch.testing.assert_close(r.predicted["q"][:, -1], target, atol=1e-3, rtol=0)
    one = infer_action(model, {"q_prev": q0}, {"q": target}, options=ActionOptions(sampling=FAST))
    torch.testing.assert_close(one.predicted["q"], torch.tensor([[0.5], [-0.5]]))


def test_horizon_inits_and_replayed_noise_through_the_twin():
    model = _integrator()
    q0 = torch.zeros(2, 1)
    target = torch.ones(2, 1)
    seq = torch.full((2, 4, 1), 0.25)
    r = infer_action(
        model,
        {"q_prev": q0},
        {"q": target},
        options=ActionOptions(horizon=4, init={"a": seq}, lr=1e-9),
        num_steps=1,
    )
    torch.testing.assert_close(r.actions["a"], seq)
    held = infer_action(
        model,
        {"q_prev": q0},
        {"q": target},
        options=ActionOptions(horizon=4, init={"a": torch.full((2, 1), 0.5)}),
    )
    torch.testing.assert_close(held.predicted["q"][:, -1], target, atol=1e-3, rtol=0)
    # a sole ReplayNoise(u, default="expected") plans through the twin too; zeros are the expected residuals
    zero = infer_action(
        ReplayNoise({"q": q0}, default="expected")(model), {"q_prev": q0}, {"q": target}, options=ActionOptions(horizon=4)
    )
    plain = infer_action(model, {"q_prev": q0}, {"q": target}, options=ActionOptions(horizon=4))
    torch.testing.assert_close(zero.actions["a"], plain.actions["a"])
    bad = ReplayNoise({"q": torch.zeros(3, 1)}, default="expected")(model)
    with pytest.raises(ValueError, match=r"noise\['q'\] has shape \(3, 1\)"):
        infer_action(bad, {"q_prev": q0}, {"q": target}, options=ActionOptions(horizon=4))


# ---------------------------------------------------------------- randomness


def test_planner_leaves_the_global_rngs_alone(plant):
    q_prev, target, _ = reachable_targets(8, 6)
    random.seed(1)
    np.random.seed(1)
    torch.manual_seed(1)
    before = (random.getstate(), np.random.get_state()[1].copy(), torch.get_rng_state())
    cfg = SamplingConfig(population=16, elites=4, iterations=2, noise_beta=1.0, refine_steps=3)
    for horizon in (1, 3):
        infer_action(
            plant,
            {"q_prev": q_prev},
            {"q": target},
            options=ActionOptions(sampling=cfg, horizon=horizon, init="random"),
            seed=2,
        )
    assert random.getstate() == before[0]
    assert np.array_equal(np.random.get_state()[1], before[1])
    assert torch.equal(torch.get_rng_state(), before[2])


def test_seed_decides_the_samples(plant):
    q_prev, target, _ = reachable_targets(8, 7)
    cfg = SamplingConfig(population=8, elites=2, iterations=1, refine_steps=0)
    runs = [
        infer_action(plant, {"q_prev": q_prev}, {"q": target}, options=ActionOptions(sampling=cfg), seed=s)
        for s in (0, 0, 1)
    ]
    assert torch.equal(runs[0].actions["a"], runs[1].actions["a"])
    assert not torch.equal(runs[0].actions["a"], runs[2].actions["a"])


# ---------------------------------------------------------------- bad input


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"horizon": 0}, "horizon must be a positive int, got 0"),
        ({"target_at": "middle"}, "target_at 'middle' unknown"),
        ({"sampling": {"population": 8}}, "sampling must be None or a SamplingConfig"),
        ({"risk": "max"}, "risk 'max' unknown"),
        ({"risk": ("disagreement", "big")}, "disagreement weight must be a finite number"),
        ({"risk": ("variance", 1.0)}, "risk must be None, 'mean', \\('disagreement', weight\\) or \\('quantile', q\\)"),
        (
            {"horizon": 2, "init": {"a": torch.zeros(2, 3, 1)}},
            "init\\['a'\\] has 3 steps, expected horizon 2",
        ),
        (
            {"horizon": 2, "state": {"q_prev": torch.zeros(2, 1), "q": torch.zeros(2, 1)}},
            "state may give roots only",
        ),
    ],
)
def test_bad_planner_input(plant, kwargs, match):
    kwargs = dict(kwargs)
    state = kwargs.pop("state", {"q_prev": torch.zeros(2, 1)})
    with pytest.raises(ValueError, match=match):
        infer_action(plant, state, {"q": torch.zeros(2, 1)}, options=ActionOptions(**kwargs))


def test_disagreement_needs_targets(plant):
    with pytest.raises(ValueError, match="needs targets"):
        infer_action(
            plant,
            {"q_prev": torch.zeros(2, 1)},
            options=ActionOptions(log_preference=lambda p: p["q"][..., 0], risk=("disagreement", 1.0)),
        )
