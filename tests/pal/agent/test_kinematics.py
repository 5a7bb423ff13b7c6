"""The body's kinematics read from its MJCF: the effector's forward kinematics and the joint limits as known laws."""

from dataclasses import replace

import gymnasium
import mujoco
import numpy as np
import pytest
import torch

from models import JointLimitMechanism, KinematicMechanism
from pal.agent import Agent, AgentConfig, ModelConfig, pusher_spec, reacher_spec
from pal.agent.config import MODEL_SCHEDULE
from pal.agent.kinematics import known_mechanisms, mjcf_chain, point_chains

TINY = AgentConfig(
    model=ModelConfig(
        hidden=(8,), members=2, kinematics="mjcf", schedule=replace(MODEL_SCHEDULE, epochs=2, patience=None)
    ),
    reset_every=None,
    servo=False,
)

#: A hinge, then a slide joint between the world and the tip: the chain takes hinges only.
SLIDER = """
<mujoco><worldbody><body name="a"><joint name="h" type="hinge" axis="0 0 1"/><geom size="0.1"/>
<body name="b" pos="0.3 0 0"><joint name="s" type="slide" axis="1 0 0"/><geom size="0.1"/>
<body name="tip" pos="0.2 0 0"><geom size="0.05"/></body></body></body></worldbody></mujoco>
"""


@pytest.mark.parametrize("env_id, spec", [("Pusher-v5", pusher_spec()), ("Reacher-v5", reacher_spec())])
def test_the_chain_read_from_the_mjcf_places_the_effector_where_mujoco_does(env_id, spec):
    env = gymnasium.make(env_id)
    model = env.unwrapped.model
    data = mujoco.MjData(model)
    chain, columns = mjcf_chain(model, spec.joints, spec.effector_body)
    assert columns == list(range(len(spec.joints)))
    rng = np.random.default_rng(0)
    for _ in range(20):
        q = rng.uniform(-2.0, 2.0, len(spec.joints))
        data.qpos[: len(q)] = q
        mujoco.mj_kinematics(model, data)
        x = chain(torch.as_tensor(q)).numpy()
        np.testing.assert_allclose(x, data.body(spec.effector_body).xpos, atol=1e-9, rtol=0)
    env.close()


def test_the_claw_points_are_where_mujoco_puts_the_claws_geoms():
    env = gymnasium.make("Pusher-v5")
    model, spec = env.unwrapped.model, pusher_spec()
    data = mujoco.MjData(model)
    chains, columns = point_chains(env, spec)
    assert len(chains) == 4 and columns == list(range(7))
    bar, *fingers = (model.geom(i) for i in (13, 14, 15))  # the wrist-roll link's capsules
    assert [f.size[1] for f in fingers] == pytest.approx([0.05, 0.05])
    assert bar.size[1] == pytest.approx(0.1)
    rng = np.random.default_rng(1)
    for _ in range(10):
        q = rng.uniform(-1.5, 1.5, 7)
        data.qpos[:7] = q
        mujoco.mj_kinematics(model, data)
        axis = data.geom_xmat[13].reshape(3, 3)[:, 2]  # a capsule lies along its frame's z
        ends = {tuple(np.round(data.geom_xpos[13] + k * 0.1 * axis, 9)) for k in (1, -1)}
        got = [c(torch.as_tensor(q)).numpy() for c in chains]
        assert {tuple(np.round(g, 9)) for g in got[:2]} == ends
        np.testing.assert_allclose(
            sorted(map(tuple, got[2:])), sorted(map(tuple, data.geom_xpos[[14, 15]])), atol=1e-9
        )
    with pytest.raises(ValueError, match="no effector_points"):
        point_chains(env, replace(spec, effector_points=()))
    with pytest.raises(ValueError, match=r"effector_points must be finite \(x, y, z\) triples"):
        replace(spec, effector_points=((0.0, 1.0),))


def test_an_agent_with_mjcf_kinematics_learns_the_joints_and_keeps_the_known_laws():
    env = gymnasium.make("Pusher-v5")
    agent = Agent(env, pusher_spec(), TINY, seed=0)
    dee, q = agent.model.mechanism("dee"), agent.model.mechanism("q")
    assert isinstance(dee, KinematicMechanism) and isinstance(q, JointLimitMechanism)
    before = {k: v.clone() for k, v in dee.state_dict().items()}
    agent.reset(seed=1)
    for _ in range(12):
        agent.step(agent.random_action())
    agent.refit()
    assert all(torch.equal(before[k], v) for k, v in dee.state_dict().items())
    # the joint limits of the MJCF hold a predicted angle: r_shoulder_pan_joint is limited to [-2.28, 1.71]
    out = q(torch.tensor([[1.6] + [0.0] * 6 + [0.5] + [0.0] * 6]))
    assert float(out[0, 0]) == pytest.approx(float(env.unwrapped.model.jnt_range[0, 1]))
    env.close()


def test_a_wrong_effector_body_fails_at_construction_naming_the_distance():
    env = gymnasium.make("Pusher-v5")
    spec = replace(pusher_spec(), effector_body="r_shoulder_pan_link")
    with pytest.raises(ValueError, match=r"r_shoulder_pan_link.*from the sensed .* check effector_body"):
        Agent(env, spec, TINY, seed=0)
    env.close()


def test_bad_bodies_and_envs_name_what_is_wrong():
    env = gymnasium.make("Pusher-v5")
    model = env.unwrapped.model
    spec = pusher_spec()
    with pytest.raises(ValueError, match="'hand' is not a body of the MJCF"):
        mjcf_chain(model, spec.joints, "hand")
    with pytest.raises(ValueError, match="'r_shoulder_pan_joint' on the path to 'tips_arm' is not among"):
        mjcf_chain(model, spec.joints[1:], "tips_arm")
    with pytest.raises(ValueError, match="needs a spec with an effector and its effector_body"):
        known_mechanisms(env, replace(spec, effector_body=None, effector_points=()), 1e-4)
    with pytest.raises(ValueError, match="'shoulder' of the spec is not a joint of the MJCF"):
        known_mechanisms(env, replace(spec, joints=("shoulder", *spec.joints[1:])), 1e-4)
    slider = mujoco.MjModel.from_xml_string(SLIDER)
    with pytest.raises(ValueError, match="joint 's' on the path to 'tip' is not a hinge"):
        mjcf_chain(slider, ("h", "s"), "tip")
    with pytest.raises(ValueError, match="no hinge joint on the path from the world to 'a'"):
        fixed = SLIDER.replace('<joint name="h" type="hinge" axis="0 0 1"/>', "")
        mjcf_chain(mujoco.MjModel.from_xml_string(fixed), ("s",), "a")
    with pytest.raises(ValueError, match=r"kinematics 'urdf' unknown; expected one of \['learned', 'mjcf'\]"):
        ModelConfig(kinematics="urdf")
    env.close()
    cartpole = gymnasium.make("CartPole-v1")
    with pytest.raises(ValueError, match="needs a MuJoCo env"):
        known_mechanisms(cartpole, spec, 1e-4)
