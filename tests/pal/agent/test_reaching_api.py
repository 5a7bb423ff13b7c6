"""The agent API on a Gymnasium task without a wrapper: transforms, effector goals, actuator kinds, no silent hold."""

from dataclasses import replace

import gymnasium
import numpy as np
import pytest

from pal.agent import (
    Agent,
    AgentConfig,
    EnvSpec,
    ModelConfig,
    Sensor,
    absolute_from_relative,
    angle_from_cos_sin,
    index_map,
    reacher_spec,
)
from pal.agent.body_checks import actuator_kinds
from pal.agent.config import MODEL_SCHEDULE
from pal.agent.learn import wrap_angle
from pal.baselines.reacher_ik import ReacherIK, inverse_kinematics


@pytest.fixture(scope="module")
def reacher():
    env = gymnasium.make("Reacher-v5")
    yield env
    env.close()


@pytest.mark.parametrize(
    ("make", "match"),
    [
        (lambda: Sensor(obs=(0, 1, 2), transform=angle_from_cos_sin()), "odd number"),
        (lambda: Sensor(obs=(8, 9), transform=absolute_from_relative(to=(4,))), r"to=\[4\] has 1 entries"),
        (lambda: Sensor(obs=(0, 1), transform=index_map((2,))), "index map entry 2 is out of range"),
        (lambda: Sensor(info="x", dim=2, transform=angle_from_cos_sin()), "applies to observation entries"),
        (
            lambda: EnvSpec(("a",), Sensor(obs=(0,)), effector_goal=Sensor(obs=(1, 2))),
            "effector_goal .* the spec has no effector",
        ),
        (
            lambda: EnvSpec(("a", "b"), Sensor(obs=(0, 1)), velocities=Sensor(obs=(2,))),
            "velocities has dim 1",
        ),
    ],
)
def test_bad_transforms_and_roles_are_refused_at_construction(make, match):
    with pytest.raises(ValueError, match=match):
        make()


def test_transforms_invert_in_closed_form():
    q = np.array([0.3, -2.9])
    for layout in ("blocks", "pairs"):
        t = angle_from_cos_sin(layout)
        np.testing.assert_allclose(t.apply(t.inverse(q), None), q, atol=1e-12)
    obs = np.array([0.0, 0.0, 0.0, 0.0, 0.1, -0.2])
    rel = absolute_from_relative(to=(4, 5))
    np.testing.assert_allclose(
        rel.inverse(rel.apply(np.array([0.05, 0.07]), obs), obs), [0.05, 0.07], atol=1e-12
    )


def test_reacher_reads_angles_fingertip_and_goal_without_a_wrapper(reacher):
    agent = Agent(reacher, reacher_spec(), AgentConfig(reset_every=None), seed=0)
    p = agent.reset(seed=3)
    data = reacher.unwrapped.data
    np.testing.assert_allclose(p.q, data.qpos[:2], atol=1e-9)
    np.testing.assert_allclose(p.v, data.qvel[:2], atol=1e-9)
    np.testing.assert_allclose(p.effector, reacher.unwrapped.get_body_com("fingertip")[:2], atol=1e-9)
    np.testing.assert_allclose(p.goals["fingertip"], reacher.unwrapped.get_body_com("target")[:2], atol=1e-9)
    assert agent.servo is False  # read from the MJCF: two motors
    assert agent.spec.periodic  # angles from cos/sin: a step across +-pi is wrapped
    np.testing.assert_allclose(
        wrap_angle(np.array([3.1 - (-3.1), -6.2, 0.5])), [6.2 - 2 * np.pi, -6.2 + 2 * np.pi, 0.5]
    )


def test_cosines_read_as_angles_and_wrong_servo_setting_fail_naming_the_value(reacher):
    cosines = replace(reacher_spec(), angles=Sensor(obs=(0, 1)), velocities=None)
    with pytest.raises(ValueError, match="the spec reads .* for joint 'joint0', but MuJoCo's qpos is"):
        Agent(reacher, cosines)
    with pytest.raises(
        ValueError, match=r"servo=True, but actuator 'actuator 0 \(on joint joint0\)' is a motor"
    ):
        Agent(reacher, reacher_spec(), AgentConfig(servo=True))
    pairs = replace(reacher_spec(), angles=Sensor(obs=(0, 1, 2, 3), transform=angle_from_cos_sin("pairs")))
    with pytest.raises(ValueError, match=r"angles: cos\^2 \+ sin\^2 of pair 0 is"):
        Agent(reacher, pairs)
    swapped = replace(reacher_spec(), velocities=Sensor(obs=(8, 9)), effector=None, effector_goal=None)
    with pytest.raises(ValueError, match="velocities: the spec reads"):
        Agent(reacher, swapped)
    assert set(actuator_kinds(reacher.unwrapped.model).values()) == {"motor"}


@pytest.mark.slow
def test_effector_goals_plan_and_a_goal_mode_without_goals_raises(reacher):
    tiny = AgentConfig(
        model=ModelConfig(hidden=(8,), members=2, schedule=replace(MODEL_SCHEDULE, epochs=2, patience=None)),
        reset_every=None,
    )
    bare = replace(reacher_spec(), effector_goal=None)
    idle = Agent(reacher, bare, tiny, seed=0)
    idle.reset()
    with pytest.raises(ValueError, match="the goal mode has nothing to reach"):
        idle.decide("goal")
    with pytest.raises(ValueError, match="the goal mode has nothing to reach"):
        Agent(reacher, bare, tiny, seed=0, mode="goal")
    with pytest.raises(ValueError, match="mode 'reach' unknown"):
        Agent(reacher, bare, tiny, seed=0, mode="reach")
    with pytest.raises(ValueError, match="mode 'reach' unknown"):
        idle.run(1, "reach")
    assert len(Agent(reacher, bare, tiny, seed=0, mode="babble").run(3)) == 3
    with pytest.raises(ValueError, match="the effector is 'fingertip'"):
        Agent(reacher, bare, tiny, goal={"tip": [0.1, 0.0]})
    agent = Agent(reacher, bare, tiny, seed=0, goal={"fingertip": [0.1, 0.1]})
    agent.run(40, "babble")
    agent.refit()
    agent.reset()
    d = agent.decide("goal")
    assert d.mode == "goal" and set(d.targets) == {"fingertip"} and d.action.shape == (2,)
    assert d.predicted["fingertip"].shape == (2,) and np.isfinite(d.objective)


def test_the_ik_baseline_reaches_a_goal_and_refuses_bad_input(reacher):
    np.testing.assert_allclose(inverse_kinematics(np.array([0.21, 0.0]) - 1e-9), [0.0, 0.0], atol=1e-3)
    obs, _ = reacher.reset(seed=0)
    controller = ReacherIK()
    for _ in range(50):
        obs, *_ = reacher.step(controller(obs).astype(np.float32))
    assert np.linalg.norm(obs[8:10]) < 1e-3
    with pytest.raises(ValueError, match="expected Reacher-v5's finite"):
        controller(np.zeros(9))
