"""Replanning every k steps (``PlanConfig.replan_every``): the agent's, the baseline's and the simulator's MPC."""

from dataclasses import replace

import gymnasium
import numpy as np
import pytest
import torch

from inference.planning import shift_plan
from pal.agent import Agent, AgentConfig, PlanConfig, pusher_spec
from pal.agent.replan import Replanning
from pal.baselines.pets import BaselineConfig, CEMPlanner, ProbabilisticEnsemble
from pal.baselines.simulator_mpc import SimulatorMPC, pusher_observation
from pal.experiments.closed_loop import pusher
from pal.experiments.closed_loop.pusher_runs import step_cost

#: The tiny pusher planner, horizon 4, planning every 3 steps.
EVERY_3 = replace(pusher.TINY.plan, action=replace(pusher.TINY.plan.action, horizon=4), replan_every=3)


def test_a_plan_shifted_by_k_steps_repeats_its_last_action_k_times():
    seq = torch.arange(8.0).reshape(4, 2)  # a_t = (2t, 2t + 1)
    np.testing.assert_array_equal(shift_plan(seq, steps=2).numpy(), [[4, 5], [6, 7], [6, 7], [6, 7]])
    np.testing.assert_array_equal(shift_plan(seq, steps=9).numpy(), [[6, 7]] * 4)
    np.testing.assert_array_equal(
        shift_plan(seq, torch.zeros(2), steps=3).numpy(), [[6, 7], [0, 0], [0, 0], [0, 0]]
    )
    assert torch.equal(shift_plan(seq), shift_plan(seq, steps=1))
    with pytest.raises(ValueError, match="steps must be a positive int, got 0"):
        shift_plan(seq, steps=0)


def test_replanning_plans_every_k_steps_and_never_past_the_horizon():
    r = Replanning(3)
    assert r.due(horizon=5)  # no plan yet
    with pytest.raises(ValueError, match="no plan to take an action from"):
        r.take()
    schedule = []
    for _ in range(7):
        if r.due(horizon=5):
            r.planned()
            schedule.append("plan")
        else:
            schedule.append(r.take())
    assert schedule == ["plan", 1, 2, "plan", 1, 2, "plan"]
    assert r.shift() == 1
    r.take()
    assert r.shift() == 2
    r.reset()
    assert r.due(horizon=5) and r.shift() == 1
    short = Replanning(10)
    short.planned()
    assert [short.due(horizon=2), short.take(), short.due(horizon=2)] == [False, 1, True]


@pytest.mark.parametrize("every", [0, -1, 1.5, True])
def test_a_replanning_interval_below_one_is_refused(every):
    with pytest.raises(ValueError, match=r"replan_every must be a positive int, got"):
        PlanConfig(replan_every=every)


def _counting(monkeypatch, module):
    """Count the searches that ``module`` runs (each is a plan)."""
    calls = []
    search = module.cross_entropy_search

    def counted(*args, **kwargs):
        calls.append(1)
        return search(*args, **kwargs)

    monkeypatch.setattr(module, "cross_entropy_search", counted)
    return calls


def test_the_simulators_mpc_executes_its_plan_between_plans(monkeypatch):
    import pal.baselines.simulator_mpc as module

    calls = _counting(monkeypatch, module)
    env = gymnasium.make("Pusher-v5")
    env.reset(seed=4)
    plan = replace(EVERY_3, action_weight=0.0)  # the tip moves towards the object: plans that are not 0
    planner = SimulatorMPC(env, plan, step_cost(plan), pusher_observation, ("tips_arm", "object", "goal"))
    first, final = planner.act()
    sequence = planner.plan.clone()
    assert bool(sequence.abs().sum() > 0)
    env.step(first.astype(np.float32))
    for k in (1, 2):
        action, held_final = planner.act()
        np.testing.assert_array_equal(action, sequence[k].numpy().astype(np.float64))
        np.testing.assert_array_equal(held_final, final)
        env.step(action.astype(np.float32))
    assert len(calls) == 1
    planner.act()  # the fourth step plans again
    assert len(calls) == 2
    env.close()


def test_the_baselines_mpc_executes_its_plan_between_plans(monkeypatch):
    import pal.baselines.pets as module

    calls = _counting(monkeypatch, module)
    g = np.random.default_rng(0)
    obs, act = g.normal(size=(200, 3)), g.uniform(-1, 1, size=(200, 2))
    model = ProbabilisticEnsemble(3, 2, BaselineConfig(members=2, hidden=(16,), epochs=20), seed=0)
    model.fit(obs, act, obs + 0.3 * np.concatenate([act, act[:, :1]], 1))
    config = PlanConfig(action=replace(PlanConfig().action, horizon=4), replan_every=3)
    planner = CEMPlanner(model, -np.ones(2), np.ones(2), config, lambda o, a: o[..., 0].abs(), seed=0)
    state = np.array([0.4, 0.0, 0.0])
    _, final = planner.act(state)
    sequence = planner._mean.clone()
    for k in (1, 2):  # other observations: the held plan does not read them
        action, held_final = planner.act(state + k)
        np.testing.assert_array_equal(action, sequence[k].numpy().astype(np.float64))
        np.testing.assert_array_equal(held_final, final)
    assert len(calls) == 1
    planner.act(state)
    planner.reset()
    planner.act(state)  # a new episode plans at once
    assert len(calls) == 3


def test_the_agent_executes_its_plan_between_plans_and_replans_for_a_new_goal(monkeypatch):
    import pal.agent.loop as module

    plans = []
    original = module.plan_batch
    monkeypatch.setattr(module, "plan_batch", lambda *a, **k: plans.append(1) or original(*a, **k))
    cfg = AgentConfig(model=pusher.TINY.model, plan=EVERY_3, reset_every=None, servo=False)
    agent = Agent(gymnasium.make("Pusher-v5"), pusher_spec(), cfg, seed=0)
    agent.run(8, "babble")
    agent.refit()
    agent.reset(seed=5)
    first = agent.decide("goal")
    agent.step(first.action)
    held = agent.decide("goal")
    assert len(plans) == 1
    np.testing.assert_array_equal(held.action, first.sequence[1])
    assert held.predicted.keys() == first.predicted.keys() and held.objective == first.objective
    assert set(held.step_mean) == {"object"}  # the one-step prediction of the executed action
    agent.step(held.action)
    agent.goal = {"object": np.asarray(first.targets["object"]) + 0.01}  # the goal moved: plan now
    moved = agent.decide("goal")
    assert len(plans) == 2
    np.testing.assert_allclose(moved.targets["object"], agent.goal["object"])
    agent.step(moved.action)
    agent.reset(seed=6)
    agent.decide("goal")  # a new episode plans at once
    assert len(plans) == 3
