"""The ``pusher-data`` experiment: restored states replay the environment, both data sets are scored (tiny sizes)."""

from dataclasses import replace

import gymnasium
import mujoco
import numpy as np
import pytest

from pal.experiments.closed_loop import pusher_data
from pal.experiments.closed_loop.pusher_data import Config, Continuations, StartFromState


def test_a_restored_state_continues_exactly_as_the_environment_did():
    env = StartFromState(gymnasium.make("Pusher-v5"))
    obs, _ = env.reset(seed=3)
    sim = env.unwrapped
    rng = np.random.default_rng(0)
    torques = rng.uniform(-2, 2, size=(8, 7)).astype(np.float32)
    path, saved = [obs], None
    for t, a in enumerate(torques):
        if t == 3:
            saved = np.empty(mujoco.mj_stateSize(sim.model, mujoco.mjtState.mjSTATE_FULLPHYSICS))
            mujoco.mj_getState(sim.model, sim.data, saved, mujoco.mjtState.mjSTATE_FULLPHYSICS)
        path.append(env.step(a)[0])
    again, _ = env.reset(seed=11, options={"state": saved})  # another seed: the state decides
    np.testing.assert_allclose(again[:14], path[3][:14], atol=1e-12)  # joint angles and velocities exactly
    # body positions of the restored state itself; the environment's lag one substep (< 5 mm here)
    np.testing.assert_allclose(again[14:], path[3][14:], atol=5e-3)
    for t in range(3, 8):
        np.testing.assert_allclose(env.step(torques[t])[0], path[t + 1], atol=1e-9)
    plain, _ = env.reset(seed=3)
    np.testing.assert_allclose(plain, path[0], atol=0)  # without a state, the environment's own reset
    with pytest.raises(ValueError, match=r"state has shape \(5,\); expected a finite full-physics state"):
        env.reset(seed=3, options={"state": np.zeros(5)})
    bad = saved.copy()
    bad[4] = np.nan
    with pytest.raises(ValueError, match="expected a finite full-physics state"):
        env.reset(seed=3, options={"state": bad})
    env.close()


@pytest.mark.slow
def test_pusher_data_scores_the_expert_data_and_the_data_with_continuations(tiny_run):
    rep = tiny_run("experiment", "pusher-data").report
    tiny = pusher_data.TINY
    m = rep.metrics
    assert list(m) == ["expert", "expert + continuations"]
    steps = tiny.expert_episodes * tiny.episode_steps
    c = tiny.continuations
    starts = len(range(0, tiny.episode_steps - c.steps + 1, c.every))
    assert m["expert"]["transitions"] == steps
    assert (
        m["expert + continuations"]["transitions"]
        == steps + tiny.expert_episodes * starts * c.per_state * c.steps
    )
    (target,) = rep.targets
    assert target.name == "continuations_rho_obj_gain" and target.verdict == "not evaluated"  # 1 episode, 1 probe
    for row in m.values():
        assert row["probes"] == 1 and 0 <= row["moving"] <= row["transitions"]
        assert row["rho"] is None or -1.0 <= row["rho"] <= 1.0


@pytest.mark.parametrize(
    ("changes", "match"),
    [
        ({"expert_episodes": 0}, "expert_episodes must be"),
        ({"episode_steps": 101}, "episode_steps must be"),
        ({"continuations": 3}, "continuations must be a Continuations, got int"),
        ({"episode_steps": 10}, "continuations.steps 25 exceeds episode_steps 10"),
    ],
)
def test_pusher_data_refuses_bad_settings(changes, match):
    with pytest.raises(ValueError, match=match):
        replace(Config(), **changes)


@pytest.mark.parametrize(
    ("changes", "match"),
    [
        ({"every": 0}, "continuations.every must be"),
        ({"per_state": -1}, "continuations.per_state must be"),
        ({"noise": 0.1}, "continuations.noise must be an Exploration, got float"),
    ],
)
def test_continuations_refuse_bad_settings(changes, match):
    with pytest.raises(ValueError, match=match):
        Continuations(**changes)
