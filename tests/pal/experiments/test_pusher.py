"""The pusher experiment on Gymnasium's Pusher-v5 and its PETS-style baseline (tiny budgets)."""

import json

import numpy as np
import pytest
import torch

from pal.agent import PlanConfig
from pal.baselines.pets import BaselineConfig, CEMPlanner, ProbabilisticEnsemble
from pal.experiments.closed_loop import pusher


@pytest.mark.slow
def test_pusher_reports_the_three_controllers_at_equal_steps(tiny_run):
    rep = tiny_run("experiment", "pusher").report
    m = rep.metrics
    assert m["env_steps"] == pusher.TINY.babble_steps + pusher.TINY.train_episodes * pusher.TINY.episode_steps
    for c in pusher.CONTROLLERS:
        assert m[c]["goals"] == pusher.TINY.eval_goals * pusher.TINY.runs
        assert m[c]["final_planar"]["median"] <= m[c]["final_distance"]["median"]  # the goal sits lower
    assert (
        rep.target("pal_over_baseline").value
        == m["pal"]["final_planar"]["median"] / m["baseline"]["final_planar"]["median"]
    )
    assert 0 < rep.target("pal_step_cpu_seconds").value < 5.0
    assert m["curve"]["steps"] == [pusher.TINY.babble_steps + pusher.TINY.episode_steps]
    assert np.asarray(m["curve"]["pal"]).shape == (1, 1)
    assert rep.figures["learning_curve"].axes[0].get_xlabel() == "environment steps"
    assert len(rep.figures["paths"].axes[0].get_lines()) == 2 * len(pusher.CONTROLLERS) + 1
    json.dumps(rep.metrics, allow_nan=False)


def test_the_baseline_learns_a_linear_system_and_plans_with_it():
    g = np.random.default_rng(0)
    obs = g.normal(size=(400, 3))
    act = g.uniform(-1, 1, size=(400, 2))
    nxt = obs + 0.3 * np.concatenate([act, act[:, :1]], 1)
    model = ProbabilisticEnsemble(3, 2, BaselineConfig(members=2, hidden=(32,), epochs=200), seed=0)
    losses = model.fit(obs, act, nxt)
    assert losses[-1] < losses[0]
    x = torch.as_tensor(obs[:50], dtype=torch.float32).expand(2, 50, 3)
    a = torch.as_tensor(act[:50], dtype=torch.float32).expand(2, 50, 2)
    with torch.no_grad():
        err = (model(x, a) - torch.as_tensor(nxt[:50], dtype=torch.float32)).abs().mean()
    assert float(err) < 0.05
    # drive the first coordinate to 0: CEM picks the action that moves it there
    cost = lambda o, a: o[..., 0].abs()  # noqa: E731
    config = PlanConfig(horizon=2, population=64, elites=8, iterations=3)
    planner = CEMPlanner(model, -np.ones(2), np.ones(2), config, cost, seed=0)
    action, final = planner.act(np.array([0.4, 0.0, 0.0]))
    assert action[0] < -0.3 and abs(final[0]) < 0.15
