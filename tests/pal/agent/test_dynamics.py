"""The body's joint dynamics read from its MJCF: dq and v stepped by MuJoCo as known laws."""

from dataclasses import replace

import gymnasium
import mujoco
import numpy as np
import pytest
import torch

from models.mechanisms import make_mechanism
from pal.agent import Agent, AgentConfig, ModelConfig, pusher_spec
from pal.agent.config import MODEL_SCHEDULE
from pal.agent.dynamics import SimulatedJointMechanism, dynamics_mechanisms, mobile_geoms
from pal.experiments.closed_loop import pusher

TINY = AgentConfig(
    model=ModelConfig(
        hidden=(8,),
        members=2,
        kinematics="mjcf",
        dynamics="mjcf",
        schedule=replace(MODEL_SCHEDULE, epochs=2, patience=None),
    ),
    plan=pusher.TINY.plan,  # the sampling planner alone: MuJoCo gives no gradient
    reset_every=None,
    servo=False,
)


def _transitions(env, steps, seed):
    """``(act, q_prev, v_prev, q, v)`` rows of random torques from ``env.reset(seed=seed)``."""
    obs, _ = env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    rows = []
    for _ in range(steps):
        act = rng.uniform(-2.0, 2.0, 7)
        nxt, *_ = env.step(act.astype(np.float32))
        rows.append((act, obs[:7], obs[7:14], nxt[:7], nxt[7:14]))
        obs = nxt
    return [np.stack(c) for c in zip(*rows, strict=True)]


def test_the_mjcf_dynamics_step_the_joints_as_the_environment_does_away_from_contact():
    env = gymnasium.make("Pusher-v5")
    mechs = dynamics_mechanisms(env, pusher_spec(), 1e-4, servo=False)
    act, q_prev, v_prev, q, v = _transitions(env, 20, seed=3)
    z = torch.as_tensor(np.concatenate([act, q_prev, v_prev], axis=1))
    dq_hat, v_hat = mechs["dq"](z).numpy(), mechs["v"](z).numpy()
    env.close()
    # random torques keep the hand far from the object, so no contact: the same physics up to
    # the float32 of the observation (Gymnasium's obs is float64 here; the action is float32)
    np.testing.assert_allclose(dq_hat, q - q_prev, atol=1e-5)
    np.testing.assert_allclose(v_hat, v, atol=1e-3)
    assert not mechs["dq"].trainable and mechs["dq"].simulator is mechs["v"].simulator


def test_the_body_presses_on_the_table_as_in_the_environment_and_passes_through_objects():
    env = gymnasium.make("Pusher-v5")
    mechs = dynamics_mechanisms(env, pusher_spec(), 1e-4, servo=False)
    model = env.unwrapped.model
    named = lambda kind, i: mujoco.mj_id2name(model, kind, i)  # noqa: E731
    off = {named(mujoco.mjtObj.mjOBJ_BODY, model.geom_bodyid[g]) for g in mobile_geoms(model, range(7))}
    assert off == {"object", "goal"}  # moved by their own slide joints, not by the arm's
    obs, _ = env.reset(seed=0)
    table = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "table")
    wrist = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "r_wrist_roll_link")  # the claw's capsules
    data, pressed, err = env.unwrapped.data, 0, []
    for _ in range(30):  # the shoulder's lift torque lowers the claw onto the table
        act = np.array([0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0])
        z = torch.as_tensor(np.concatenate([act, obs[:7], obs[7:14]])[None])
        nxt, *_ = env.step(act.astype(np.float32))
        err.append(np.abs(mechs["dq"](z).numpy()[0] - (nxt[:7] - obs[:7])).max())
        claw = [c for c in data.contact[: data.ncon] if table in (c.geom1, c.geom2)]
        pressed += any(model.geom_bodyid[c.geom1 + c.geom2 - table] == wrist for c in claw)
        obs = nxt
    env.close()
    assert pressed >= 5, "the claw never pressed on the table: the test lost its contact"
    assert max(err) < 1e-5  # with every contact off, 0.018 rad off in one step


def test_batches_of_any_shape_and_the_serialised_mechanism_agree():
    env = gymnasium.make("Pusher-v5")
    mechs = dynamics_mechanisms(env, pusher_spec(), 1e-4, servo=False)
    env.close()
    g = torch.Generator().manual_seed(0)
    z = torch.rand(2, 3, 21, generator=g, dtype=torch.float64) - 0.5
    out = mechs["v"](z)
    assert out.shape == (2, 3, 7)
    flat = mechs["v"](z.reshape(6, 21)).reshape(2, 3, 7)
    torch.testing.assert_close(flat, out, rtol=0, atol=0)
    picks = [3, 0, 3, 5, 0, 3]  # rows in any order, repeated or not, each get their own result
    again_rows = mechs["v"](z.reshape(6, 21)[picks])
    torch.testing.assert_close(again_rows, flat.reshape(6, 7)[picks], rtol=0, atol=0)
    again = make_mechanism(mechs["dq"].config())
    assert isinstance(again, SimulatedJointMechanism) and again.simulator is not mechs["dq"].simulator
    torch.testing.assert_close(again(z), mechs["dq"](z), rtol=0, atol=0)


def test_the_mjcf_dynamics_refuse_gradients_bad_sites_and_learned_kinematics():
    env = gymnasium.make("Pusher-v5")
    mech = dynamics_mechanisms(env, pusher_spec(), 1e-4, servo=False)["dq"]
    with pytest.raises(ValueError, match="have no gradient"):
        mech(torch.zeros(4, 21, dtype=torch.float64, requires_grad=True))
    with pytest.raises(ValueError, match="output must be 'dq' or 'v', got 'q'"):
        SimulatedJointMechanism(mech.simulator.xml, pusher_spec().joints, 5, "q")
    with pytest.raises(ValueError, match=r"joints \['elbow'\] are not joints of the MJCF"):
        SimulatedJointMechanism(mech.simulator.xml, ("elbow",), 5, "dq")
    with pytest.raises(ValueError, match="needs torque actions"):
        dynamics_mechanisms(env, pusher_spec(), 1e-4, servo=True)
    env.close()
    with pytest.raises(ValueError, match="dynamics='mjcf' needs kinematics='mjcf'"):
        ModelConfig(dynamics="mjcf")
    with pytest.raises(ValueError, match="dynamics"):
        ModelConfig(kinematics="mjcf", dynamics="simulated")


def test_an_agent_with_the_mjcf_body_learns_only_the_object():
    env = gymnasium.make("Pusher-v5")
    agent = Agent(env, pusher_spec(), TINY, seed=0)
    assert isinstance(agent.model.mechanism("dq"), SimulatedJointMechanism)
    assert isinstance(agent.model.mechanism("v"), SimulatedJointMechanism)
    before = {k: v.clone() for k, v in agent.model.mechanism("dq").state_dict().items()}
    agent.reset(seed=1)
    for _ in range(12):
        agent.step(agent.random_action())
    agent.refit()
    assert all(torch.equal(before[k], v) for k, v in agent.model.mechanism("dq").state_dict().items())
    plan = agent.plan({"object": np.array([0.5, 0.0, -0.275])})
    assert plan.action.shape == (7,) and np.isfinite(plan.action).all()
    # the members' particles share the body: a rollout steps MuJoCo once per candidate, not per member
    sim, seen = agent.model.mechanism("dq").simulator, []
    step = sim.step
    sim.step = lambda z: seen.append(tuple(z.shape)) or step(z)
    belief = {k: torch.as_tensor(v)[None] for k, v in agent.belief().items()}
    acts = torch.zeros(3, 4, 7, dtype=agent.model.dtype)
    agent.model.rollout({k: belief[k].expand(3, -1) for k in belief}, {"act": acts}, members=True)
    assert seen and all(s == (3, 21) for s in seen), seen
    env.close()
