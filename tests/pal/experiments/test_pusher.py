"""The pusher experiment on Gymnasium's Pusher-v5 and its PETS-style baseline (tiny budgets)."""

import json

import numpy as np
import pytest
import torch

from pal.agent import PlanConfig
from pal.baselines.pets import BaselineConfig, CEMPlanner, ProbabilisticEnsemble
from pal.experiments.closed_loop import pusher
from pal.experiments.closed_loop.pusher_runs import Episode


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
    config = PlanConfig()  # horizon 2, population 64, 8 elites, 3 iterations
    planner = CEMPlanner(model, -np.ones(2), np.ones(2), config, cost, seed=0)
    action, final = planner.act(np.array([0.4, 0.0, 0.0]))
    assert action[0] < -0.3 and abs(final[0]) < 0.15


def _episode(final: float, path: list[list[float]]) -> Episode:
    return Episode(final, final, 0.2, 0.1, 0.01, 0.01, path, [0.0, 0.0])


def _synthetic(moving: dict[str, float]) -> tuple[dict, dict]:
    """Pooled evaluation episodes where controller c moves the object by moving[c] metres."""
    config = pusher.TINY
    pooled = {
        c: [_episode(0.2 - moving[c], [[0.1, 0.1], [0.1 + moving[c], 0.1]])] for c in pusher.CONTROLLERS
    }
    per_seed = {config.seed: {"evaluation": pooled}}
    metrics = {c: pusher._controller(config, per_seed, pooled[c], c) for c in pusher.CONTROLLERS}
    return metrics, pooled


def test_a_ratio_of_two_controllers_that_never_moved_the_object_is_not_evaluated():
    metrics, pooled = _synthetic({"pal": 0.0, "baseline": 0.0, "random": 0.0})
    targets = {t.name: t for t in pusher._targets(metrics, pooled)}
    ratio = targets["pal_over_baseline"]
    assert ratio.value == 1.0 and ratio.verdict == "not evaluated" and ratio.met is False
    assert "moved > 5 mm" in ratio.precondition.reason
    assert targets["pal_over_random"].verdict == "not evaluated"
    assert targets["pal_final_distance"].precondition is None


def test_a_ratio_counts_once_both_controllers_moved_the_object():
    metrics, pooled = _synthetic({"pal": 0.05, "baseline": 0.02, "random": 0.001})
    targets = {t.name: t for t in pusher._targets(metrics, pooled)}
    assert metrics["pal"]["max_object_displacement"] == pytest.approx(0.05)
    assert targets["pal_over_baseline"].evaluated and targets["pal_over_baseline"].verdict == "met"
    assert targets["pal_over_baseline"].value == pytest.approx(0.15 / 0.18)
    assert targets["pal_over_random"].verdict == "not evaluated"  # random moved it 1 mm only
