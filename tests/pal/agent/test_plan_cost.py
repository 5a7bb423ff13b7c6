"""The planner's preference: PETS's L1 Pusher cost, the behind-the-object shaping, and its defaults."""

from dataclasses import replace

import numpy as np
import pytest
import torch

from inference import ActionOptions
from pal.agent import PlanConfig
from pal.agent.config import PLAN_ACTION, PLAN_SAMPLING
from pal.agent.plan import behind, preference
from pal.experiments.closed_loop.pusher import PLAN
from pal.experiments.closed_loop.pusher_runs import step_cost


def _values():
    g = torch.Generator().manual_seed(0)
    return {
        "pos.object": torch.randn(4, 3, generator=g),
        "ee": torch.randn(4, 3, generator=g),
        "act": torch.randn(4, 7, generator=g),
        "q_prev": torch.randn(4, 7, generator=g),
    }


def test_pusher_defaults_are_horizon_25_and_petss_l1_cost_reweighted_for_100_step_episodes():
    assert PLAN.action.horizon == 25 and PLAN.preference == "l1"
    # PETS's (1.25, 0.5, 0.1) with the object term 10x and the action term 0.1x (pusher-ceiling)
    assert (PLAN.goal_weight, PLAN.effector_weight, PLAN.action_weight) == (12.5, 0.5, 0.01)
    assert PLAN.behind_weight == 0.0  # the shaping term is off by default
    s = PLAN.action.sampling
    assert s.noise_beta == 2.0 and s.keep_elites == 0.3 and s.population_decay == 1.25


def test_the_agents_default_plans_risk_aware_with_icem():
    assert PLAN_ACTION.risk == "mean" and PlanConfig().action.risk == "mean"
    assert PLAN_SAMPLING.noise_beta == 2.0 and PLAN_SAMPLING.keep_elites == 0.3


def test_l1_preference_is_the_hand_computed_pets_cost():
    v = _values()
    target = torch.tensor([[0.1, -0.2, 0.0]])
    pets = replace(PLAN, goal_weight=1.25, action_weight=0.1)
    log_p = preference({"object": target}, pets, effector=True)(v)
    obj, tip, act = v["pos.object"], v["ee"], v["act"]
    want = 1.25 * (obj - target).abs().sum(-1) + 0.5 * (tip - obj).abs().sum(-1) + 0.1 * act.pow(2).sum(-1)
    torch.testing.assert_close(-log_p, want, atol=1e-6, rtol=0)


@pytest.mark.parametrize("behind_weight", [0.0, 0.7])
def test_the_baselines_step_cost_equals_the_agents_preference(behind_weight):
    config = replace(PLAN, behind_weight=behind_weight)
    v = _values()
    goal = torch.tensor([0.3, 0.1, -0.05])
    obs = torch.zeros(4, 23)
    obs[:, 14:17], obs[:, 17:20], obs[:, 20:23] = v["ee"], v["pos.object"], goal
    cost = step_cost(config)(obs, v["act"])
    log_p = preference({"object": goal[None]}, config, effector=True)(v)
    torch.testing.assert_close(cost, -log_p, atol=1e-6, rtol=0)


def test_behind_is_on_the_far_side_from_the_target():
    pos = torch.tensor([[0.2, 0.1, 0.0]])
    target = torch.tensor([[0.2, 0.5, -0.05]])  # straight ahead in +y
    torch.testing.assert_close(behind(pos, target, 0.05), torch.tensor([[0.2, 0.05]]), atol=1e-6, rtol=0)
    config = replace(PLAN, behind_weight=1.0, effector_weight=0.0, goal_weight=0.0, action_weight=0.0)
    on_spot = {"pos.object": pos, "ee": torch.tensor([[0.2, 0.05, 0.3]]), "act": torch.zeros(1, 7)}
    ahead = {**on_spot, "ee": torch.tensor([[0.2, 0.15, 0.3]])}
    pref = preference({"object": target}, config, effector=True)
    assert float(pref(on_spot)) == pytest.approx(0.0, abs=1e-5)  # x-y only: the height is free
    assert float(pref(ahead)) == pytest.approx(-0.1, abs=1e-5)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"preference": "l2"}, "preference"),
        ({"behind_offset": 0.0}, "behind_offset"),
        ({"goal_weight": -1.0}, "goal_weight"),
        ({"action": replace(PLAN_ACTION, horizon=0)}, "action.horizon must be a positive int, got 0"),
    ],
)
def test_bad_plan_settings_are_refused(kwargs, match):
    with pytest.raises(ValueError, match=match):
        PlanConfig(**kwargs)


def test_the_baseline_plans_with_the_shared_icem_search():
    """A 1-D integrator o' = o + a under the baseline's planner: it drives o to 0 and warm-starts shifted."""
    from pal.baselines.pets import CEMPlanner

    class Integrator(torch.nn.Module):
        config = type("C", (), {"members": 2})()

        def forward(self, obs, act):
            return obs + act

    config = replace(
        PLAN, action=ActionOptions(horizon=4, sampling=replace(PLAN.action.sampling, population=32, elites=4))
    )
    planner = CEMPlanner(
        Integrator(), -np.ones(1) * 0.3, np.ones(1) * 0.3, config, lambda o, a: o[..., 0].abs(), seed=0
    )
    action, final = planner.act(np.array([0.5]))
    assert action[0] < -0.1 and abs(final[0]) < 0.1  # towards 0, and predicted to arrive
    assert planner._mean.shape == (4, 1) and float(planner._mean[0, 0]) == pytest.approx(action[0])
