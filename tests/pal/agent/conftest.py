"""Fixtures shared by the agent's tests."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import gymnasium
import numpy as np
import pytest
import torch

from pal.agent import Agent, AgentConfig, ModelConfig, pusher_spec
from pal.agent.graph_frame import frame_columns
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


def _weighs_measurements(agent: Agent, std: float) -> None:
    """Filter one step whose measurements are shifted 2.5 cm with sd ``std``; check the posterior weighs them.

    A sharp measurement (std < 1 cm) wins; a vague one leaves the model's prediction, computed
    from the same evidence through the estimator's blanket (with the push frame's ``local.o``
    from :func:`pal.agent.graph_frame.frame_columns` when the model has it).
    """
    agent.reset(seed=5)
    prev, est_prev = agent.percept, dict(agent.estimate)
    offset = np.array([0.02, -0.015])
    shifted = {
        o: replace(m, position=m.position + offset, std=np.full(2, std)) for o, m in prev.measurements.items()
    }
    est = agent.estimator.update(agent.model, prev, est_prev, {}, replace(prev, measurements=shifted), seed=0)
    objects = tuple(shifted)
    blanket = agent.estimator.blanket(agent.model, objects)
    roots: dict[str, np.ndarray] = {}
    for o in objects:
        rel = prev.effector - np.append(est_prev[o], 0.0)
        given = {f"pos_prev.{o}": est_prev[o], f"rel_prev.{o}": rel, f"rel.{o}": rel, f"contact.{o}": [0.0]}
        roots.update({k: np.asarray(v, dtype=np.float64)[None] for k, v in given.items()})
        if f"local.{o}" in blanket.graph.roots:
            roots[f"local.{o}"] = frame_columns(agent.model, roots)[f"local.{o}"]
    pred = blanket.predict({k: torch.as_tensor(v, dtype=torch.float32) for k, v in roots.items()})
    for o in objects:
        assert np.isfinite(est[o]).all()
        if std < 0.01:  # a sharp measurement wins
            np.testing.assert_allclose(est[o], shifted[o].position, atol=0.004)
        else:  # a vague one is ignored: the model's prediction stays (within the short SVI's noise)
            p = pred[f"pos.{o}"][0].numpy()
            assert np.linalg.norm(est[o] - p) < 0.01 < np.linalg.norm(est[o] - shifted[o].position)


@pytest.fixture(scope="session")
def weighs_measurements() -> Callable[[Agent, float], None]:
    """``check(agent, std)``: the fitted agent's estimator weighs a shifted measurement by its sd."""
    return _weighs_measurements
