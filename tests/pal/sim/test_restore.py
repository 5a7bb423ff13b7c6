"""Restarting a Gymnasium MuJoCo environment from saved states: exact continuation, the recorded trace, bad input."""

import gymnasium
import numpy as np
import pytest

from pal.baselines.simulator_mpc import PUSHER_BODIES, pusher_observation
from pal.sim.restore import StartFromState, find_wrapper


def _pusher() -> StartFromState:
    return StartFromState(gymnasium.make("Pusher-v5"), pusher_observation, PUSHER_BODIES)


def test_a_restored_state_continues_exactly_as_the_environment_did():
    env = _pusher()
    obs, _ = env.reset(seed=3)
    rng = np.random.default_rng(0)
    torques = rng.uniform(-2, 2, size=(8, 7)).astype(np.float32)
    path = [obs] + [env.step(a)[0] for a in torques]
    states, actions = env.states, env.actions
    assert states.shape == (8, env.size) and actions.shape == (8, 7)
    np.testing.assert_array_equal(actions, torques.astype(np.float64))
    again, _ = env.reset(seed=11, options={"state": states[3]})  # another seed: the state decides
    assert env.states.shape == (0, env.size)  # a reset starts a new trace
    np.testing.assert_allclose(again[:14], path[3][:14], atol=1e-12)  # joint angles and velocities exactly
    # body positions of the restored state itself; the environment's lag one substep (< 5 mm here)
    np.testing.assert_allclose(again[14:], path[3][14:], atol=5e-3)
    for t in range(3, 8):
        np.testing.assert_allclose(env.step(torques[t])[0], path[t + 1], atol=1e-9)
    np.testing.assert_allclose(env.states[0], states[3], atol=0)  # the trace restarts at the restored state
    plain, _ = env.reset(seed=3)
    np.testing.assert_allclose(plain, path[0], atol=0)  # without a state, the environment's own reset
    env.close()


def test_bad_states_bodies_and_environments_are_refused():
    env = _pusher()
    env.reset(seed=3)
    env.step(np.zeros(7, dtype=np.float32))
    saved = env.states[0]
    with pytest.raises(ValueError, match=r"state has shape \(5,\); expected a finite full-physics state"):
        env.reset(seed=3, options={"state": np.zeros(5)})
    bad = saved.copy()
    bad[4] = np.nan
    with pytest.raises(ValueError, match="expected a finite full-physics state"):
        env.reset(seed=3, options={"state": bad})
    env.close()
    with pytest.raises(ValueError, match=r"bodies \['hand'\] are not in the model"):
        StartFromState(gymnasium.make("Pusher-v5"), pusher_observation, ("hand",))
    with pytest.raises(ValueError, match="is not a Gymnasium MuJoCo environment: it has no 'model'"):
        StartFromState(gymnasium.make("CartPole-v1"), pusher_observation, ())


def test_find_wrapper_looks_through_the_wrapper_chain():
    inner = _pusher()
    outer = gymnasium.wrappers.TimeAwareObservation(inner)
    assert find_wrapper(outer, StartFromState) is inner
    assert find_wrapper(gymnasium.make("Pusher-v5"), StartFromState) is None
    inner.close()
