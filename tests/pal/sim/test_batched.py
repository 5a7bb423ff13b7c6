"""Native batched physics (``mujoco.rollout``) against the serial Python loop, bit for bit."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from pal.experiments.world_model.data import JointData, Realizer
from pal.sim.babbling import BabbleConfig, collect, replay
from pal.sim.batched import FULLPHYSICS, BatchReplayer, join_state, split_state
from pal.sim.env import BabblingEnv


@pytest.fixture(scope="module")
def arm_data():
    config = BabbleConfig(
        body="arm", seed=4, steps=30, frame_skip=5, reset_every=11, reset_noise=0.2, chunk_size=30
    )
    return collect(config)


def test_split_and_join_states_follow_mj_getState(arm_data):
    env = BabblingEnv("arm", frame_skip=5)
    m = env.model
    full, warm = split_state(m, arm_data.states)
    for i in (0, 7, 29):
        env.set_state(arm_data.states[i])
        expected = np.empty(mujoco.mj_stateSize(m, FULLPHYSICS))
        mujoco.mj_getState(m, env.data, expected, FULLPHYSICS)
        assert np.array_equal(full[i], expected)
        assert np.array_equal(warm[i], env.data.qacc_warmstart)
    assert np.array_equal(join_state(m, full, warm), arm_data.states)


@pytest.mark.parametrize(
    "body, settings",
    [
        ("finger", {"reset_every": 7, "reset_noise": 0.3, "chunk_size": 9}),
        ("arm", {"reset_every": 13, "reset_noise": 0.1, "chunk_size": 16, "policy": "ou"}),
    ],
)
def test_babbling_through_rollout_equals_the_loop(body, settings):
    config = BabbleConfig(body=body, seed=3, steps=40, frame_skip=5, **settings)
    loop, native = collect(config), collect(config, backend="rollout")
    assert np.array_equal(loop.states, native.states)
    assert np.array_equal(loop.ctrl, native.ctrl)
    assert loop.columns.keys() == native.columns.keys()
    for key in loop.columns:
        assert np.array_equal(loop.columns[key], native.columns[key]), key


@pytest.mark.parametrize("threads", [0, 2])
def test_batched_replay_equals_serial_replay(arm_data, threads):
    env = BabblingEnv("arm", frame_skip=5)
    rng = np.random.default_rng(0)
    rows = rng.choice(len(arm_data), 12, replace=False)
    ctrls = arm_data.ctrl[rows].astype(np.float64) + rng.normal(0.0, 0.5, (12, arm_data.ctrl.shape[1]))
    expected = np.array([replay(env, arm_data.states[i], c) for i, c in zip(rows, ctrls, strict=True)])
    with BatchReplayer(env, threads=threads) as replayer:
        got = replayer.step(arm_data.states[rows], ctrls)
    assert got.shape == expected.shape == (12, len(env.joint_names))
    assert np.array_equal(got, expected)


def test_a_rollout_stopped_by_a_warning_is_replayed_like_mj_step(arm_data):
    env = BabblingEnv("arm", frame_skip=5)
    states = arm_data.states[:3].copy()
    qvel = 1 + env.model.nq  # FULLPHYSICS and STATE_SPEC both start with time, qpos, qvel
    states[1, qvel] = 1e11  # above mjMAXVAL: mj_step warns and resets
    ctrls = arm_data.ctrl[:3].astype(np.float64)
    expected = np.array([replay(env, s, c) for s, c in zip(states, ctrls, strict=True)])
    got = BatchReplayer(env).step(states, ctrls)
    assert np.array_equal(got, expected)


def test_realized_outcomes_batched_equal_serial(arm_data):
    joint = JointData.select(arm_data, "finger")
    realizer = Realizer(arm_data, joint, "arm")
    rows = np.array([0, 3, 10, 11, 29])
    actions = np.linspace(*joint.action_range, len(rows))
    serial = realizer.outcomes(rows, actions, batched=False)
    assert np.array_equal(realizer.outcomes(rows, actions), serial)
    assert np.array_equal(realizer.outcomes(rows, actions[:, None]), serial)


def test_bad_batches_are_refused(arm_data):
    env = BabblingEnv("arm", frame_skip=5)
    replayer = BatchReplayer(env)
    states, ctrls = arm_data.states[:2], arm_data.ctrl[:2].astype(np.float64)
    bad = ctrls.copy()
    bad[1, 0] = np.nan
    with pytest.raises(ValueError, match=r"ctrls rows \[1\] contain NaN"):
        replayer.step(states, bad)
    with pytest.raises(ValueError, match=r"ctrls has shape \(1, 8\), expected \(2, 8\)"):
        replayer.step(states, ctrls[:1])
    with pytest.raises(ValueError, match=r"states has shape \(2, 3\)"):
        replayer.step(states[:, :3], ctrls)
    with pytest.raises(ValueError, match="threads must be an integer >= 0, got -1"):
        BatchReplayer(env, threads=-1)
    with pytest.raises(ValueError, match="unknown backend 'gpu'"):
        collect(BabbleConfig(body="finger", steps=2), backend="gpu")
    replayer.close()
    with pytest.raises(RuntimeError, match="closed"):
        replayer.step(states, ctrls)
