"""Agents in lockstep: the goal-mode MPC steps of several agents over one world model, planned together.

Evaluating a learner on G goals runs G episodes of the same model. Run one after the other,
every MPC step pays the Python cost of each rollout step of the world model (about 16 sites,
25 steps, 3 iterations) for one unit; in lockstep the G agents that need a plan at a step get it
from one :func:`pal.agent.plan.plan_batch` call, whose candidates ``(R, G, H, A)`` go through
each rollout step together, so that cost is paid once per step for all of them.

Each agent decides as ``agent.decide("goal")`` would (:meth:`pal.agent.Agent.goal_pending`,
:meth:`~pal.agent.Agent.plan_request`, :meth:`~pal.agent.Agent.goal_decided`), with one
difference: the batch's samples come from one generator (seeded by the first planning agent's
draw), so an agent's plans differ from those it makes alone by their random draws.
"""

from __future__ import annotations

from collections.abc import Sequence

from pal.agent.decision import Decision
from pal.agent.loop import Agent
from pal.agent.plan import plan_batch

__all__ = ["decide_goal_together"]


def decide_goal_together(agents: Sequence[Agent]) -> list[Decision]:
    """One goal-mode decision per agent, the new plans made in one batched search (module docstring).

    Args:
        agents: agents over one world model (the same object) with the same planner settings,
            each reset; residual correction must be off when more than one agent plans.

    Returns:
        the decisions, in the order of ``agents``.

    Raises:
        ValueError: no agents, agents with different models, planner settings or effectors, or
            as :meth:`pal.agent.Agent.decide`.
    """
    if not agents:
        raise ValueError("decide_goal_together needs at least one agent, got none")
    first = agents[0]
    for k, agent in enumerate(agents):
        if agent.model is not first.model:
            raise ValueError(f"agent {k} has another world model than agent 0; lockstep plans over one model")
        if agent.config.plan != first.config.plan or agent.effector_name != first.effector_name:
            raise ValueError(f"agent {k} has other planner settings or another effector than agent 0")
    decisions: list[Decision | None] = [None] * len(agents)
    waiting = []
    for k, agent in enumerate(agents):
        pending = agent.goal_pending()
        if isinstance(pending, Decision):
            decisions[k] = pending
        else:
            waiting.append((k, pending))
    if waiting:
        requests = [agents[k].plan_request(goal) for k, (goal, _) in waiting]
        plans = plan_batch(first.model, requests, first.config.plan, effector=first.effector_name)
        for (k, (_, now)), p in zip(waiting, plans, strict=True):
            decisions[k] = agents[k].goal_decided(agents[k].adopt(p), now)
    return [d for d in decisions if d is not None]
