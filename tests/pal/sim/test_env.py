"""BabblingEnv and the shipped bodies: API checks, determinism, exact replay, bad input."""

import math
import warnings

import gymnasium
import mujoco
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from pal.sim import BODIES, STATE_SPEC, BabblingEnv, MJCFError, body_path, load_body
from pal.sim.env import ENV_ID

# check_env warnings that are deliberate (see pal.sim.env): velocities are unbounded and soft
# limits let q overshoot its range, and the action space is the thesis's raw ctrl range.
EXPECTED_WARNINGS = (
    "observation space minimum value is -infinity",
    "observation space maximum value is infinity",
    "symmetric and normalized space",
)


def rollout(env, actions, seed):
    obs, _ = env.reset(seed=seed)
    out = [obs]
    for a in actions:
        out.append(env.step(a)[0])
    return np.array(out)


@pytest.mark.parametrize("body", BODIES)
def test_env_checker_passes_with_only_the_documented_warnings(body):
    env = gymnasium.make(ENV_ID, model=body).unwrapped
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env)
    unexpected = [str(w.message) for w in caught if not any(e in str(w.message) for e in EXPECTED_WARNINGS)]
    assert unexpected == []


def test_bodies_load_from_the_package_not_the_working_directory(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert body_path("finger").is_file() and body_path("finger").parent.name == "assets"
    finger = load_body("finger")
    assert (finger.nq, finger.nu, finger.ncam) == (1, 1, 1)
    arm = load_body("arm")
    assert arm.nu == 8 and arm.opt.gravity[2] == pytest.approx(-9.81)


def test_finger_parameters_follow_the_notes():
    env = BabblingEnv("finger")
    m, j = env.model, env.joint_ids[0]
    assert env.joint_names == ("finger",) and env.joint_actuators == {"finger": "finger"}
    np.testing.assert_allclose(m.jnt_range[j], np.radians([-160.0, 8.0]), rtol=1e-12)
    assert m.jnt_stiffness[j] == pytest.approx(0.017) and m.dof_damping[j] == pytest.approx(0.018)
    assert m.qpos_spring[0] == pytest.approx(math.radians(-40.0))
    assert m.actuator_gear[0, 0] == pytest.approx(0.69)
    np.testing.assert_allclose(m.actuator_ctrlrange[0], [-1.0, 0.33])
    assert m.opt.timestep == 0.005 and m.opt.iterations == 50
    assert m.opt.solver == mujoco.mjtSolver.mjSOL_NEWTON
    assert env.frame_skip == 50 and env.dt == pytest.approx(0.25)


def test_arm_gears_and_ranges_follow_the_notes():
    env = BabblingEnv("arm")
    gears = dict(zip(env.actuator_names, env.model.actuator_gear[:, 0], strict=True))
    assert gears == pytest.approx(
        {
            "shoulder_horizontal": 1.8,
            "shoulder_abduction": 4,
            "shoulder_rotation": 2.5,
            "elbow": 3.6,
            "wrist_rotation": 0.7,
            "wrist_flexion": 1.24,
            "wrist_ulnar": 0.95,
            "finger": 0.69,
        }
    )
    assert env.actuator_ranges["shoulder_abduction"] == pytest.approx((-0.6875, 1.0))
    assert env.actuator_ranges["wrist_ulnar"] == pytest.approx((-0.87, 1.0))
    assert env.joint_actuators == {j: j for j in env.joint_names} and len(env.joint_names) == 8


def test_same_seed_gives_identical_rollouts():
    actions = np.random.default_rng(0).uniform([-1], [0.33], size=(20, 1))
    a = rollout(BabblingEnv("finger", reset_noise=0.1), actions, seed=3)
    b = rollout(BabblingEnv("finger", reset_noise=0.1), actions, seed=3)
    c = rollout(BabblingEnv("finger", reset_noise=0.1), actions, seed=4)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a[0], c[0])  # the seeded reset noise differs


def test_reset_goes_to_qpos0_without_noise():
    env = BabblingEnv("arm", frame_skip=5)
    env.reset(seed=0)
    env.step(env.action_space.sample())
    obs, info = env.reset(seed=1)
    np.testing.assert_array_equal(obs, np.zeros(16))
    assert info["time"] == 0.0


@pytest.mark.parametrize("body", BODIES)
def test_set_state_replays_a_recorded_step_bit_for_bit(body):
    env = BabblingEnv(body)
    env.reset(seed=0)
    rng = np.random.default_rng(1)
    states, actions, after = [], [], []
    for _ in range(15):
        states.append(env.get_state())
        actions.append(rng.uniform(env.ctrl_low, env.ctrl_high))
        after.append(env.step(actions[-1])[0])
    fresh = BabblingEnv(body)
    for i in rng.permutation(15):
        fresh.set_state(states[i])
        np.testing.assert_array_equal(fresh.step(actions[i])[0], after[i])
    assert env.get_state().shape == (mujoco.mj_stateSize(env.model, STATE_SPEC),)


def test_reset_option_state_restores_a_state():
    env = BabblingEnv("finger")
    env.reset(seed=0)
    env.step([-0.5])
    state = env.get_state()
    obs = env.step([0.2])[0]
    env.reset(options={"state": state})
    np.testing.assert_array_equal(env.step([0.2])[0], obs)


def test_out_of_range_actions_are_clipped_like_mujoco():
    env = BabblingEnv("finger")
    env.reset(seed=0)
    state = env.get_state()
    _, _, _, _, info = env.step([5.0])
    assert info["ctrl"].tolist() == [0.33]
    clipped = env.get_state()
    # MuJoCo's own clamping of the raw value gives the same physics
    env.set_state(state)
    env.data.ctrl[0] = 5.0
    mujoco.mj_step(env.model, env.data, env.frame_skip)
    np.testing.assert_array_equal(env.get_state(), clipped)


def test_selection_by_name_and_observation_layout():
    env = BabblingEnv("arm", joints=["elbow", "finger"], actuators=["finger"])
    assert env.observation_space.shape == (4,) and env.action_space.shape == (1,)
    assert env.joint_actuators == {"finger": "finger"}
    obs, _ = env.reset(seed=0)
    obs, *_ = env.step([-1.0])
    np.testing.assert_array_equal(obs[:2], env.data.qpos[[3, 7]])
    np.testing.assert_array_equal(obs[2:], env.data.qvel[[3, 7]])


def test_unknown_names_are_listed():
    with pytest.raises(ValueError, match=r"unknown joint name\(s\) \['knee'\].*'finger'"):
        BabblingEnv("finger", joints=["knee"])
    with pytest.raises(ValueError, match=r"unknown actuator name\(s\) \['thumb'\].*\['finger'\]"):
        BabblingEnv("finger", actuators=["thumb"])
    with pytest.raises(ValueError, match="unknown body 'leg'"):
        body_path("leg")
    with pytest.raises(ValueError, match="the string 'finger'"):
        BabblingEnv("finger", joints="finger")


def test_missing_and_malformed_mjcf_name_the_path(tmp_path):
    missing = tmp_path / "nope.xml"
    with pytest.raises(MJCFError, match="nope.xml.*does not exist"):
        BabblingEnv(missing)
    bad = tmp_path / "bad.xml"
    bad.write_text("<mujoco><worldbody><body><geom type='sphere'")
    with pytest.raises(MJCFError, match=r"bad\.xml") as err:
        BabblingEnv(bad)
    assert isinstance(err.value, ValueError)
    wrong = tmp_path / "wrong.xml"
    wrong.write_text("<mujoco><worldbody><geom type='spheroid' size='1'/></worldbody></mujoco>")
    with pytest.raises(MJCFError, match=r"wrong\.xml.*spheroid"):
        BabblingEnv(wrong)


def test_custom_mjcf_file_works(tmp_path):
    path = tmp_path / "pendulum.xml"
    path.write_text(
        "<mujoco><worldbody><body><joint name='hinge' type='hinge' axis='0 1 0'/>"
        "<geom type='capsule' fromto='0 0 0 0 0 -0.3' size='0.02'/></body></worldbody>"
        "<actuator><motor name='m' joint='hinge' ctrlrange='-1 1'/></actuator></mujoco>"
    )
    env = BabblingEnv(path, frame_skip=2)
    assert env.joint_names == ("hinge",) and env.joint_actuators == {"hinge": "m"}
    env.reset(seed=0)
    assert env.step([1.0])[0][1] > 0


@pytest.mark.parametrize(
    ("action", "match"),
    [
        ([0.1, 0.2], r"action has shape \(2,\), expected \(1,\)"),
        (0.1, r"action has shape \(\), expected \(1,\)"),
        ([[0.1]], r"action has shape \(1, 1\)"),
        ([float("nan")], "contains NaN or inf"),
        ([float("inf")], "contains NaN or inf"),
    ],
)
def test_bad_actions_raise(action, match):
    env = BabblingEnv("finger")
    env.reset(seed=0)
    with pytest.raises(ValueError, match=match):
        env.step(action)


def test_bad_arguments_and_states_raise():
    with pytest.raises(ValueError, match="frame_skip must be a positive int, got 0"):
        BabblingEnv("finger", frame_skip=0)
    with pytest.raises(ValueError, match="reset_noise"):
        BabblingEnv("finger", reset_noise=-1.0)
    env = BabblingEnv("finger")
    with pytest.raises(ValueError, match=r"state has shape \(3,\), expected \(4,\)"):
        env.set_state(np.zeros(3))
    with pytest.raises(ValueError, match="NaN or inf"):
        env.set_state(np.full(4, np.nan))
    with pytest.raises(ValueError, match="unknown reset option"):
        env.reset(options={"qpos": 0})
