"""Agents in lockstep (:mod:`pal.agent.lockstep`), the batched planner under them (:func:`pal.agent.plan.plan_batch`), and the baseline's planners in lockstep."""

from dataclasses import replace

import gymnasium
import numpy as np
import pytest
import torch

from pal.agent import Agent, AgentConfig, PlanConfig, pusher_spec
from pal.agent.lockstep import decide_goal_together
from pal.agent.plan import PlanRequest, plan_batch
from pal.baselines.pets import BaselineConfig, CEMPlanner, ProbabilisticEnsemble, act_together
from pal.baselines.pets_aggregate import PetsLearner
from pal.experiments.closed_loop import pusher
from pal.experiments.closed_loop.pusher_runs import step_cost

PLAN = replace(pusher.TINY.plan, action=replace(pusher.TINY.plan.action, horizon=4))
CONFIG = AgentConfig(model=pusher.TINY.model, plan=PLAN, reset_every=None, servo=False)


@pytest.fixture(scope="module")
def fitted():
    """An agent on Pusher-v5 fitted on a few random steps (its model is shared by the judges)."""
    agent = Agent(gymnasium.make("Pusher-v5"), pusher_spec(), CONFIG, seed=0)
    agent.run(12, "babble")
    agent.refit()
    return agent


def judges(fitted, seeds, first_seed=7):
    out = []
    for k, s in enumerate(seeds):
        judge = Agent(
            gymnasium.make("Pusher-v5"), pusher_spec(), CONFIG, seed=first_seed + k, model=fitted.model
        )
        judge.reset(seed=s)
        out.append(judge)
    return out


def test_one_agent_in_lockstep_decides_as_it_does_alone(fitted):
    (alone,), (together,) = judges(fitted, [3]), judges(fitted, [3])
    for _ in range(3):
        a = alone.decide("goal")
        (b,) = decide_goal_together([together])
        np.testing.assert_array_equal(a.action, b.action)
        np.testing.assert_array_equal(a.sequence, b.sequence)
        assert a.objective == b.objective and a.mode == b.mode == "goal"
        alone.step(a.action)
        together.step(b.action)


def test_each_unit_of_a_batch_is_planned_from_its_own_belief_for_its_own_target(fitted):
    agents = judges(fitted, [3, 4, 5])
    requests = [a.plan_request({"object": a.percept.goals["object"]}) for a in agents]
    assert len({tuple(r.belief["pos_prev.object"]) for r in requests}) == 3  # three different starts
    plans = plan_batch(fitted.model, requests, PLAN)
    for r, p in zip(requests, plans, strict=True):
        np.testing.assert_array_equal(p.targets["object"], r.targets["object"])
        initial = {
            k: torch.as_tensor(np.asarray(v)[None], dtype=fitted.model.dtype) for k, v in r.belief.items()
        }
        with torch.no_grad():
            path = fitted.model.rollout(
                initial, {"act": torch.as_tensor(p.sequence[None], dtype=fitted.model.dtype)}
            )
        np.testing.assert_allclose(
            p.predicted["object"], path["pos.object"][0, -1].numpy(), rtol=0, atol=1e-5
        )
        low, high = fitted.model.bounds("act")
        assert np.all(p.sequence >= low.numpy() - 1e-6) and np.all(p.sequence <= high.numpy() + 1e-6)
    assert not np.array_equal(plans[0].sequence, plans[1].sequence)


def test_lockstep_decisions_are_adopted_as_each_agents_plan(fitted):
    agents = judges(fitted, [3, 4])
    decisions = decide_goal_together(agents)
    for agent, d in zip(agents, decisions, strict=True):
        assert d.mode == "goal" and agent._plan is not None
        np.testing.assert_array_equal(agent._plan.action, d.action)
        agent.step(d.action)
    again = decide_goal_together(agents)
    assert all(d.mode == "goal" for d in again)


def test_bad_batches_are_refused_by_name(fitted):
    agents = judges(fitted, [3, 4])
    with pytest.raises(ValueError, match="at least one agent"):
        decide_goal_together([])
    other = Agent(gymnasium.make("Pusher-v5"), pusher_spec(), CONFIG, seed=1)
    other.reset(seed=2)
    with pytest.raises(ValueError, match="agent 1 has another world model"):
        decide_goal_together([agents[0], other])
    with pytest.raises(ValueError, match="at least one request"):
        plan_batch(fitted.model, [], PLAN)
    r = agents[0].plan_request({"object": agents[0].percept.goals["object"]})
    short = PlanRequest({k: v for k, v in r.belief.items() if k != "q_prev"}, r.targets, 1)
    with pytest.raises(ValueError, match="request 1 has belief"):
        plan_batch(fitted.model, [r, short], PLAN)
    noisy = replace(r, noise={"dpos.object": np.zeros(3)})
    with pytest.raises(ValueError, match="residuals .* one unit only; got them with 2 requests"):
        plan_batch(fitted.model, [r, noisy], PLAN)


def _pets_planners(n, **settings):
    """n planners over one small ensemble of ``obs' = obs + 0.3 [a, a_0]``, cost ``|obs_0|``."""
    g = np.random.default_rng(0)
    obs, act = g.normal(size=(200, 3)), g.uniform(-1, 1, size=(200, 2))
    model = ProbabilisticEnsemble(3, 2, BaselineConfig(members=2, hidden=(16,), epochs=30), seed=0)
    model.fit(obs, act, obs + 0.3 * np.concatenate([act, act[:, :1]], 1))
    config = PlanConfig(action=replace(PlanConfig().action, horizon=4), **settings)

    def cost(o, a):
        return o[..., 0].abs()

    return [CEMPlanner(model, -np.ones(2), np.ones(2), config, cost, seed=k) for k in range(n)]


def test_the_baselines_planners_search_together_each_for_its_own_observation():
    planners = _pets_planners(3)
    obs = np.array([[0.6, 0.0, 0.0], [-0.6, 0.0, 0.0], [0.6, 0.5, -0.5]])
    acted = act_together(planners, obs)
    for k, (action, final) in enumerate(acted):
        mean = planners[k]._mean
        with torch.no_grad():
            _, expected = planners[k].costs(torch.as_tensor(obs[k : k + 1], dtype=torch.float32), mean[None])
        np.testing.assert_allclose(final, expected[0].numpy(), rtol=0, atol=1e-6)
        np.testing.assert_array_equal(action, mean[0].numpy().astype(np.float64))
    # the cost pulls obs_0 to 0: each unit pushes its own way
    assert acted[0][0][0] < 0 < acted[1][0][0] and acted[2][0][0] < 0
    assert abs(acted[0][1][0]) < 0.6 and abs(acted[1][1][0]) < 0.6


def test_planners_that_hold_a_plan_take_its_next_action_and_only_the_others_search(monkeypatch):
    import pal.baselines.pets as module

    searches = []
    original = module.cross_entropy_search
    monkeypatch.setattr(
        module, "cross_entropy_search", lambda *a, **k: searches.append(a[1].shape[0]) or original(*a, **k)
    )
    planners = _pets_planners(2, replan_every=2)
    obs = np.array([[0.6, 0.0, 0.0], [-0.6, 0.0, 0.0]])
    first = act_together(planners, obs)
    planners[1].reset()  # a new episode for the second one: it plans again, the first holds
    second = act_together(planners, obs)
    assert searches == [2, 1]
    np.testing.assert_array_equal(second[0][0], planners[0]._mean[1].numpy().astype(np.float64))
    assert not np.array_equal(second[0][0], first[0][0])
    with pytest.raises(ValueError, match="at least one planner"):
        act_together([], obs)
    with pytest.raises(ValueError, match=r"obs has shape \(3,\), expected \(2, D\)"):
        act_together(planners, obs[0])
    other = _pets_planners(1)[0]
    with pytest.raises(ValueError, match="over one ensemble"):
        act_together([planners[0], other], obs)


def test_the_baselines_evaluation_episodes_run_in_lockstep():
    plan = replace(PLAN, action=replace(PLAN.action, horizon=3))
    env = gymnasium.make("Pusher-v5")
    learner = PetsLearner(
        env, BaselineConfig(members=2, hidden=(8,), epochs=1), plan, step_cost(plan), seed=0
    )
    learner.run(env, 1, 6, True, True)
    learner.refit()
    envs = [gymnasium.make("Pusher-v5") for _ in range(3)]
    episodes = learner.run_together(envs, [4, 5, 6], 5)
    for e, seed in zip(episodes, [4, 5, 6], strict=True):
        assert e.observations.shape == (6, 23) and e.predicted.shape == (5, 23) and e.cpu == []
        reset, _ = gymnasium.make("Pusher-v5").reset(seed=seed)
        np.testing.assert_allclose(e.observations[0], reset)
    assert len({float(e.observations[0, 17]) for e in episodes}) == 3  # three object starts
