"""The pushing world: gymnasium contract, determinism, exact replay, contacts, camera, bad input."""

import warnings

import gymnasium
import mujoco
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from pal.baselines.scripted_pusher import forward_kinematics, inverse_kinematics
from pal.sim.pushing import ENV_ID, JOINTS, PushingEnv, PushingLayout

# the same deliberate warnings as BabblingEnv: unbounded velocities, raw (unnormalised) action range
EXPECTED_WARNINGS = (
    "observation space minimum value is -infinity",
    "observation space maximum value is infinity",
    "symmetric and normalized space",
)


@pytest.fixture(scope="module")
def env():
    e = PushingEnv()
    yield e
    e.close()


def rollout(env, actions, seed):
    obs, _ = env.reset(seed=seed)
    out = [np.concatenate([obs, *[p[:2] for p in env.object_positions().values()]])]
    for a in actions:
        obs, *_ = env.step(a)
        out.append(np.concatenate([obs, *[p[:2] for p in env.object_positions().values()]]))
    return np.array(out)


def test_env_checker_passes_with_only_the_documented_warnings():
    env = gymnasium.make(ENV_ID).unwrapped
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env)
    unexpected = [str(w.message) for w in caught if not any(e in str(w.message) for e in EXPECTED_WARNINGS)]
    assert unexpected == []
    assert env.joint_names == tuple(JOINTS.values()) and env.actuator_names == tuple(JOINTS)
    env.close()


def test_same_seed_same_world_and_rollout(env):
    actions = np.random.default_rng(0).uniform(env.ctrl_low, env.ctrl_high, size=(6, 2))
    a, b = rollout(env, actions, seed=3), rollout(env, actions, seed=3)
    np.testing.assert_array_equal(a, b)
    c = rollout(env, actions, seed=4)
    assert not np.array_equal(a[0], c[0])  # the objects are placed elsewhere


def test_set_state_replays_a_step_bit_for_bit(env):
    env.reset(seed=1)
    rng = np.random.default_rng(2)
    states, actions, after = [], [], []
    for _ in range(8):
        states.append(env.get_state())
        actions.append(rng.uniform(env.ctrl_low, env.ctrl_high))
        obs, _, _, _, info = env.step(actions[-1])
        after.append((obs, env.get_state(), info["touch"], info["hand"]))
    for i in rng.permutation(8):
        env.set_state(states[i])
        obs, _, _, _, info = env.step(actions[i])
        np.testing.assert_array_equal(obs, after[i][0])
        np.testing.assert_array_equal(env.get_state(), after[i][1])
        np.testing.assert_array_equal(info["touch"], after[i][2])
        np.testing.assert_array_equal(info["hand"], after[i][3])


def test_the_hand_pushes_the_box_and_feels_it(env):
    # the box sits on the hand's way from the tucked pose to the arm stretched out sideways
    env.reset(
        seed=0, options={"objects": {"box": (-0.12, 0.2, 0.0), "ball": (-0.3, -0.2, 0.0)}, "q": (-1.3, -2.3)}
    )
    before = env.object_positions()
    touched = 0.0
    for a in ((-1.3, -0.05), (0.3, -0.05), (0.6, -0.05)):
        _, _, _, _, info = env.step(np.array(a))
        touched += info["touch"][env.objects.index("box")]
    after = env.object_positions()
    assert touched > 0
    assert np.linalg.norm(after["box"][:2] - before["box"][:2]) > 0.02
    np.testing.assert_allclose(after["ball"], before["ball"], atol=1e-3)  # nothing touched the ball


def test_reset_places_objects_and_joints(env):
    obs, info = env.reset(seed=0, options={"objects": {"box": (0.05, 0.15, 30.0)}, "q": (0.1, -1.0)})
    np.testing.assert_allclose(env.object_positions()["box"][:2], [0.05, 0.15], atol=1e-9)
    np.testing.assert_allclose(obs[:2], [0.1, -1.0])
    assert info["touch"].shape == (2,) and info["hand"].shape == (3,)


def test_camera_sees_the_scene_and_knows_the_arm(env):
    env.reset(seed=0)
    frame = env.camera_frame()
    assert frame.rgb.shape == (240, 320, 3) and np.isfinite(frame.depth).all()
    arm = env.arm_mask(frame)
    assert 0 < arm.sum() < arm.size
    T = env.table_from_camera(frame)
    assert T.shape == (4, 4) and T[2, 3] > 0.3  # the camera is above the table


@pytest.mark.parametrize(
    ("options", "match"),
    [
        ({"nope": 1}, "unknown reset option"),
        ({"objects": {"boat": (0, 0, 0)}}, "unknown object"),
        ({"objects": {"box": (0, 0)}}, "expected \\(x, y, yaw_deg\\)"),
        ({"q": (0.0,)}, "reset q has shape"),
        ({"state": np.zeros(3), "q": (0.0, 0.0)}, "cannot be combined"),
    ],
)
def test_bad_reset_options(env, options, match):
    with pytest.raises(ValueError, match=match):
        env.reset(seed=0, options=options)


def test_bad_construction_and_actions(env):
    with pytest.raises(ValueError, match="objects is empty"):
        PushingEnv(objects=())
    with pytest.raises(ValueError, match="spawn_radius"):
        PushingLayout(spawn_radius=(0.3, 0.2))
    with pytest.raises(ValueError, match="render_mode"):
        PushingEnv(render_mode="human")
    with pytest.raises(ValueError, match="touch_every must be a positive int"):
        PushingEnv(touch_every=0)
    with pytest.raises(ValueError, match="expected \\(2,\\)"):
        env.step(np.zeros(3))
    with pytest.raises(ValueError, match="NaN or inf"):
        env.step(np.array([np.nan, 0.0]))


def test_link_lengths_come_from_the_model_and_drive_the_kinematics(env):
    m = env.model
    body = lambda name: int(mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, name))  # noqa: E731
    palm = int(mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "arm/palm"))
    # the MJCF's forearm body offset, and the hand body offset plus the palm geom's (arm.xml: 0.12, 0.1 + 0.03)
    upper = np.linalg.norm(m.body_pos[body("arm/forearm")][:2])
    lower = np.linalg.norm((m.body_pos[body("arm/hand")] + m.geom_pos[palm])[:2])
    np.testing.assert_allclose(env.link_lengths, (upper, lower), atol=1e-12)
    np.testing.assert_allclose(env.link_lengths, (0.12, 0.13), atol=1e-12)
    env.reset(seed=0)
    saved = env.get_state()
    for q in np.random.default_rng(0).uniform(env.ctrl_low, env.ctrl_high, size=(5, 2)):
        env.data.qpos[env.qpos_indices] = q
        np.testing.assert_allclose(forward_kinematics(env, q), env.hand_position()[:2], atol=1e-9)
        if q[1] <= 0:  # the elbow-flexed branch that inverse_kinematics returns
            np.testing.assert_allclose(inverse_kinematics(env, forward_kinematics(env, q)), q, atol=1e-6)
    env.set_state(saved)


def test_info_carries_the_view_and_the_ground_truth_for_evaluation():
    env = PushingEnv(camera=True, camera_size=(160, 120))
    _, info = env.reset(seed=2)
    assert info["rgbd"].rgb.shape == (120, 160, 3) and info["self_mask"].shape == (120, 160)
    assert 0 < info["self_mask"].sum() < info["self_mask"].size and info["table_from_camera"].shape == (4, 4)
    _, _, _, _, info = env.step(env.data.qpos[env.qpos_indices].copy())
    for name, p in env.object_positions().items():
        np.testing.assert_array_equal(info["truth"][name], p)
    np.testing.assert_array_equal(info["state"], env.get_state())
    env.close()


def test_replay_runs_a_batch_of_alternatives_exactly_as_step_does(env):
    env.reset(seed=1, options={"objects": {"box": (-0.12, 0.2, 0.0)}, "q": (-1.3, -2.3)})
    env.step(np.array([-1.3, -0.05]))
    state = env.get_state()
    actions = np.array([[0.3, -0.05], [0.6, -0.05], [-1.0, -1.0], [5.0, 0.0]])  # the last is clipped
    batch = env.replay(state, actions)
    for k, a in enumerate(actions):
        env.set_state(state)
        env.step(np.clip(a, env.ctrl_low, env.ctrl_high))
        for name, p in env.object_positions().items():
            np.testing.assert_array_equal(batch[name][k], p)
    env.set_state(state)
    np.testing.assert_array_equal(env.get_state(), state)  # the environment's own state is untouched
    assert (
        np.linalg.norm(batch["box"][0, :2] - batch["box"][2, :2]) > 0.01
    )  # different pushes, different outcomes
    with pytest.raises(ValueError, match="expected finite \\(B, 2\\)"):
        env.replay(state, np.zeros((2, 3)))
    with pytest.raises(ValueError, match="get_state\\(\\) vector"):
        env.replay(state[:-1], actions)
