"""The planner's ceiling on Pusher-v5: MPC through MuJoCo itself predicts what the environment does."""

from dataclasses import replace

import gymnasium
import numpy as np
import pytest

from pal.baselines.simulator_mpc import SimulatorMPC, pusher_observation
from pal.experiments.closed_loop import pusher
from pal.experiments.closed_loop.pusher_runs import simulator_episode, step_cost

BODIES = ("tips_arm", "object", "goal")


def _planner(env, plan=pusher.TINY.plan, seed=0):
    return SimulatorMPC(env, plan, step_cost(plan), pusher_observation, BODIES, seed=seed)


def test_the_simulator_model_predicts_the_environment_exactly():
    env = gymnasium.make("Pusher-v5")
    env.reset(seed=3)
    planner = _planner(env)
    actions = np.random.default_rng(0).uniform(-2, 2, (1, 12, 7)).astype(np.float32)
    predicted = planner.predict(planner.state(), actions)
    realized = np.stack([env.step(a)[0] for a in actions[0]])
    env.close()
    assert predicted.shape == (1, 12, 23)
    np.testing.assert_allclose(predicted[0], realized, rtol=0, atol=1e-9)


def test_simulator_mpc_plans_reproducibly_and_its_plan_predicts_its_step():
    env = gymnasium.make("Pusher-v5")
    first = []
    for _ in range(2):
        env.reset(seed=4)
        planner = _planner(env, seed=7)
        first.append(planner.act()[0])
    state = planner.state()
    action, final = planner.act()
    env.close()
    np.testing.assert_array_equal(first[0], first[1])
    assert action.shape == (7,) and final.shape == (23,)
    assert np.all(np.abs(action) <= 2.0)
    assert np.isfinite(planner.predict(state, action[None, None])).all()


def test_simulator_episode_records_its_planning_time_and_prediction():
    env = gymnasium.make("Pusher-v5")
    plan = replace(pusher.TINY.plan, action=replace(pusher.TINY.plan.action, horizon=2))
    episode = simulator_episode(env, plan, seed=5, steps=3)
    env.close()
    assert len(episode.path) == 4 and episode.cpu is not None and episode.cpu > 0
    assert episode.predicted_final is not None and episode.predicted_final >= 0


def test_simulator_mpc_refuses_what_it_cannot_simulate():
    with pytest.raises(ValueError, match="not a Gymnasium MuJoCo environment"):
        _planner(gymnasium.make("CartPole-v1"))
    env = gymnasium.make("Pusher-v5")
    with pytest.raises(ValueError, match=r"bodies \['hand'\] are not in the model"):
        SimulatorMPC(env, pusher.TINY.plan, step_cost(pusher.TINY.plan), pusher_observation, ("hand",))
    planner = _planner(env)
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"actions must have shape \(R, H, 7\), got \(3, 7\)"):
        planner.predict(planner.state(), np.zeros((3, 7)))
    env.close()


def test_the_ceiling_grid_names_each_setting_and_refuses_empty_or_zero_axes():
    from pal.experiments.closed_loop import pusher_ceiling

    plan = pusher_ceiling.sized(pusher.PLAN, 30, 7.0, 0.5)
    assert (plan.action.sampling.population, plan.action.sampling.elites) == (30, 3)
    assert (plan.goal_weight, plan.behind_weight) == (7.0, 0.5)
    assert plan.effector_weight == pusher.PLAN.effector_weight
    with pytest.raises(ValueError, match=r"goal_weights needs at least one value, got \(\)"):
        pusher_ceiling.Config(goal_weights=())
    with pytest.raises(ValueError, match="goal_weights"):
        pusher_ceiling.Config(goal_weights=(0.0,))
    config = replace(pusher_ceiling.TINY, goal_weights=(1.0, 2.0))
    report = pusher_ceiling.run(config)
    rows = report.metrics["settings"]
    assert [r["goal_weight"] for r in rows] == [1.0, 2.0]
    assert report.metrics["chosen"] is None  # the plan's own weight is not in this grid
