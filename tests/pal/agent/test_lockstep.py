"""Agents in lockstep (:mod:`pal.agent.lockstep`) and the batched planner under them (:func:`pal.agent.plan.plan_batch`)."""

from dataclasses import replace

import gymnasium
import numpy as np
import pytest
import torch

from pal.agent import Agent, AgentConfig, pusher_spec
from pal.agent.lockstep import decide_goal_together
from pal.agent.plan import PlanRequest, plan_batch
from pal.experiments.closed_loop import pusher

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
