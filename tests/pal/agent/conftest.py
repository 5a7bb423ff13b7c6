"""Fixtures shared by the agent's tests."""

from __future__ import annotations

from collections.abc import Callable

import gymnasium
import pytest

from pal.agent import Agent, AgentConfig, ModelConfig, pusher_spec
from pal.baselines.scripted_pusher_v5 import ScriptedPusherV5

#: A reset seed of Pusher-v5 whose scripted episode pushes the object (it moves ~5 cm).
PUSHED_SEED = 1


@pytest.fixture(scope="session")
def scripted_pusher_agent() -> Callable[[ModelConfig], Agent]:
    """``make(model)``: an agent on Pusher-v5 with ``model``, fed one scripted episode (100 steps) that pushes the object."""

    def make(model: ModelConfig) -> Agent:
        agent = Agent(
            gymnasium.make("Pusher-v5"),
            pusher_spec(),
            AgentConfig(model=model, reset_every=None, servo=False),
            seed=0,
        )
        pusher = ScriptedPusherV5(agent.env)
        agent.reset(seed=PUSHED_SEED)
        for _ in range(100):
            agent.step(pusher.act()[0])
            if agent.done:
                break
        return agent

    return make
