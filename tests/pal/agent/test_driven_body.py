"""Pusher-v5's body, given by its MJCF, is rolled over the horizon before the object (:mod:`models.driven`)."""

import numpy as np
import pytest
import torch

from models.driven import driven_sites
from pal.agent.plan import plan
from pal.experiments.closed_loop import pusher
from tests.pal.agent.test_pusher_calibration import SMALL_PLAN

BODY = ["dq", "q", "v", "dee", "ee", "pts_prev", "pts"]


@pytest.mark.slow
def test_the_mjcf_body_is_driven_and_the_rollouts_and_plans_do_not_change(scripted_pusher_agent, monkeypatch):
    agent = scripted_pusher_agent(pusher.TINY.model)
    agent.refit()
    model = agent.model
    roots = {r for r in model.graph.roots if model.graph[r].lag == 0}
    assert driven_sites(model.graph, model._mech_by_name, set(model._categories), roots) == BODY
    belief, goal = agent.belief(), {"object": agent.percept.goals["object"]}
    n, h = 6, 5
    initial = {
        k: torch.as_tensor(np.asarray(v)[None], dtype=model.dtype).expand(n, -1) for k, v in belief.items()
    }
    low, high = model.bounds("act")
    act = low + (high - low) * torch.rand(n, h, low.shape[0], generator=torch.Generator().manual_seed(0))
    got = model.rollout(initial, {"act": act}, members=True)
    found = plan(model, belief, goal, SMALL_PLAN, seed=2)

    want = model.rollout(initial, {"act": act}, members=True, driven=False)
    monkeypatch.setattr("models.forward.roll_driven", lambda *args: {})  # the planner's rollouts too
    again = plan(model, belief, goal, SMALL_PLAN, seed=2)
    for name in model.graph.names:
        torch.testing.assert_close(got[name], want[name], rtol=0, atol=1e-6)
    assert float((got["q"][0, :, -1] - got["q"][0, :, 0]).abs().max()) > 1e-3  # the arm moved
    np.testing.assert_array_equal(found.sequence, again.sequence)
    assert found.loss == again.loss
