"""The objects' sites in the push frame: the graph, its symmetry, its training columns and its refusals."""

import math
from dataclasses import replace

import numpy as np
import pytest
import torch

import models
from models import Role
from pal.agent import Agent, AgentConfig, ModelConfig, build_graph, build_model, pusher_spec, pushing_spec
from pal.agent.config import MODEL_SCHEDULE
from pal.agent.graph_frame import frame_columns
from pal.sim.pushing import PushingEnv

MODEL = ModelConfig(
    members=2,
    hidden=(16,),
    kinematics="mjcf",
    dynamics="mjcf",
    position_sigma=1e-4,
    object_frame="push",
    schedule=replace(MODEL_SCHEDULE, epochs=30, patience=None, validation=0.0),
)
CONFIG = AgentConfig(model=MODEL, reset_every=None, servo=False)


@pytest.fixture(scope="module")
def agent(scripted_pusher_agent):
    """A push-frame agent on Pusher-v5 fed one scripted episode that pushes the object, then fitted."""
    a = scripted_pusher_agent(MODEL)
    a.refit()
    return a


def test_the_push_frame_graph_reads_the_claw_and_turns_back(agent):
    g = agent.graph
    assert g.parents("contact.object") == ("local.object",)
    assert g.parents("dpos.object") == ("contact.object", "local.object")
    assert g.parents("vel.object") == ("rel_prev.object", "dpos.object")
    assert g.parents("pos.object") == ("pos_prev.object", "rel_prev.object", "dpos.object")
    assert g.parents("pts") == ("q",) and g["pts"].dim == 12  # four claw points
    assert g["local.object"].dim == 2 * 3 + 2 * 12 + 3  # effector before/after, the points, momentum
    assert g["vel_prev.object"].lag_of == "vel.object"


def _turn(v: np.ndarray, angle: float) -> np.ndarray:
    """x-y of every 3-vector of ``v`` (N, 3 k) turned by ``angle`` about the vertical."""
    c, s = math.cos(angle), math.sin(angle)
    turn = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return (v.reshape(len(v), -1, 3) @ turn.T).reshape(v.shape)


def test_a_scene_turned_about_the_object_gives_the_turned_displacement(agent):
    """Equivariance by construction: turn every relative vector by a, and vel.o turns by a, contact stays."""
    rng = np.random.default_rng(0)
    n = 16
    given = {
        "rel_prev.object": rng.normal(0, 0.05, (n, 3)),
        "rel.object": rng.normal(0, 0.05, (n, 3)),
        "prel_prev.object": rng.normal(0, 0.08, (n, 12)),
        "prel.object": rng.normal(0, 0.08, (n, 12)),
        "vel_prev.object": rng.normal(0, 0.002, (n, 3)),
    }
    roots = {r: np.zeros((n, agent.graph[r].dim)) for r in agent.graph.roots}
    roots["act"] = np.zeros((n, 7))
    base = agent.model.predict({**roots, **given})
    for angle in (0.7, -2.5):
        turned = {k: _turn(v, angle) for k, v in given.items()}
        roots_t = {**roots, "vel_prev.object": turned["vel_prev.object"]}
        out = agent.model.predict({**roots_t, **turned})
        np.testing.assert_allclose(
            out["vel.object"].numpy(), _turn(base["vel.object"].numpy(), angle), atol=1e-6
        )
        np.testing.assert_array_equal(out["contact.object"].numpy(), base["contact.object"].numpy())


def test_the_training_columns_put_the_recorded_displacement_back_exactly(agent):
    _, objects = agent.history.columns("perceived", contact="moved", floor=3e-4)
    recorded = objects["object"]
    cols = frame_columns(agent.model, recorded)
    np.testing.assert_array_equal(cols["vel.object"], recorded["dpos.object"])
    x = torch.cat(
        [torch.as_tensor(cols[p], dtype=torch.float64) for p in ("rel_prev.object", "dpos.object")], -1
    )
    back = agent.model.mechanism("vel.object")(x).numpy()
    np.testing.assert_allclose(
        back, recorded["dpos.object"], atol=1e-6
    )  # dpos.o is the recorded one turned by -phi
    np.testing.assert_allclose(  # a turn keeps lengths
        np.linalg.norm(cols["dpos.object"], axis=1),
        np.linalg.norm(recorded["dpos.object"], axis=1),
        atol=1e-7,
    )
    assert cols["pts"].shape == (100, 12) and cols["local.object"].shape == (100, 33)


def test_the_push_frame_model_saves_and_loads(agent, tmp_path):
    path = tmp_path / "m.pal"
    models.save(agent.model, path)
    loaded = models.load(path)
    values = {r: torch.zeros(3, agent.graph[r].dim, dtype=agent.model.dtype) for r in agent.graph.roots}
    for name in ("pts", "local.object", "vel.object", "pos.object"):
        torch.testing.assert_close(loaded.predict(values)[name], agent.model.predict(values)[name])


# the state estimate runs a short SVI on purpose
@pytest.mark.filterwarnings("ignore::inference.PoorPosteriorWarning")
@pytest.mark.parametrize("std", [1e-4, 1.0])
def test_perceived_objects_are_filtered_through_the_push_frame(std, weighs_measurements):
    """State inference over the push frame: a sharp measurement wins, a vague one leaves the model's prediction."""
    env = PushingEnv(camera=True)
    model = ModelConfig(
        members=2, hidden=(8,), object_frame="push", schedule=replace(MODEL_SCHEDULE, epochs=3, patience=None)
    )
    agent = Agent(env, pushing_spec(), AgentConfig(model=model, reset_every=None), seed=1)
    agent.run(6, "babble")
    agent.refit()
    agent.config = replace(agent.config, estimate=replace(agent.config.estimate, num_steps=200))
    agent.estimator.config = agent.config.estimate
    blanket = agent.estimator.blanket(agent.model, ("box", "ball"))
    assert blanket.graph["local.box"].role is Role.OBSERVED and "vel.box" not in blanket.graph.names
    weighs_measurements(agent, std)
    env.close()


def test_the_estimate_reads_the_body_points_relative_to_the_previous_estimate(agent):
    """With body points, the push frame's evidence holds the claw relative to the estimate, as in training."""
    from pal.agent.estimate import _frame_evidence

    q_prev, q = np.zeros(7), np.full(7, 0.1)
    pos = np.array([[0.4, -0.1, -0.275]])
    rel, rel_after, vel_prev = (
        np.array([[0.1, 0.05, 0.0]]),
        np.array([[0.08, 0.06, 0.01]]),
        np.array([[0.0, 0.003, 0.0]]),
    )
    evidence = {
        "pos_prev.object": pos,
        "rel_prev.object": rel,
        "rel.object": rel_after,
        "vel_prev.object": vel_prev,
    }
    got = _frame_evidence(agent.model, "object", q_prev, q, evidence)
    with torch.no_grad():
        pts = agent.model.mechanism("pts")(torch.as_tensor(q[None], dtype=agent.model.dtype)).numpy()
    expected = (pts.reshape(4, 3) - pos).reshape(1, 12)
    np.testing.assert_allclose(got["prel.object"], expected, atol=1e-6)
    assert got["prel_prev.object"].shape == (1, 12) and got["local.object"].shape == (1, 33)
    # local.o: every parent, each body point on its own, turned by -phi, phi the direction of rel_prev.o
    given = {**evidence, "prel_prev.object": got["prel_prev.object"], "prel.object": got["prel.object"]}
    parents = agent.graph.parents("local.object")
    expected_local = np.concatenate(
        [_turn(np.asarray(given[n]), -math.atan2(0.05, 0.1)) for n in parents], -1
    )
    np.testing.assert_allclose(got["local.object"], expected_local, atol=1e-6)
    at = 3 * parents.index("rel_prev.object")
    np.testing.assert_allclose(
        got["local.object"][0, at : at + 3], [math.hypot(0.1, 0.05), 0.0, 0.0], atol=1e-6
    )
    assert _frame_evidence(agent.model, "ball", q_prev, q, {}) == {}  # no such site: nothing


def test_the_push_frame_refuses_what_it_cannot_do():
    with pytest.raises(ValueError, match="structure='discover' searches the world frame"):
        ModelConfig(object_frame="push", structure="discover")
    with pytest.raises(
        ValueError, match="object_frame 'object' unknown; expected one of \\['world', 'push'\\]"
    ):
        ModelConfig(object_frame="object")
    spec = pusher_spec()
    bounds = (np.full(7, -2.0), np.full(7, 2.0))
    graph = build_graph(spec, bounds, frame="push")
    with pytest.raises(ValueError, match=r"sites \['pts_prev', 'pts'\] are the body's points"):
        build_model(spec, graph, CONFIG.model)
    with pytest.raises(ValueError, match="frame 'claw' unknown"):
        build_graph(spec, bounds, frame="claw")


# the state estimate runs a short SVI on purpose
@pytest.mark.filterwarnings("ignore::inference.PoorPosteriorWarning")
def test_a_push_frame_agent_explores_and_plans_with_perceived_objects():
    """Curiosity's contact gate reads the push frame's parents; predictions are world-frame displacements."""
    from inference import SamplingConfig
    from pal.agent import CuriosityConfig
    from pal.agent.plan import one_step

    env = PushingEnv(camera=True)
    model = ModelConfig(
        members=2, hidden=(8,), object_frame="push", schedule=replace(MODEL_SCHEDULE, epochs=2, patience=None)
    )
    curiosity = CuriosityConfig(
        sampling=SamplingConfig(population=8, elites=2, iterations=1), influence_samples=4
    )
    config = AgentConfig(model=model, curiosity=curiosity, reset_every=None)
    agent = Agent(
        env, pushing_spec(), replace(config, estimate=replace(config.estimate, num_steps=5)), seed=2
    )
    agent.run(6, "babble")
    agent.refit()
    decisions = agent.run(2, "curious")
    assert len(decisions) == 2 and all(np.isfinite(d.action).all() for d in decisions)
    belief = agent.belief()
    mean, sd, members = one_step(agent.model, belief, decisions[-1].action, ("box",))
    values = {k: torch.as_tensor(np.asarray(v)[None], dtype=agent.model.dtype) for k, v in belief.items()}
    values["act"] = torch.as_tensor(decisions[-1].action[None], dtype=agent.model.dtype)
    world = agent.model.predict(values)["vel.box"][0].numpy()
    np.testing.assert_allclose(mean["box"], world, atol=1e-6)
    assert sd["box"].shape == (2,) and members["box"].shape == (2, 2)
    # its sd: dpos.box's, turned back to the world (vel.box's own sd is its definition's, 1e-4 m)
    push_sd = agent.model.predict_scale(values)["dpos.box"][0].double().numpy()
    rel = np.asarray(belief["ee_prev"])[:2] - np.asarray(belief["pos_prev.box"])[:2]
    c, s = rel / np.linalg.norm(rel)
    turn = np.array([[c, -s], [s, c]])
    np.testing.assert_allclose(sd["box"] ** 2, turn**2 @ push_sd**2, rtol=1e-4)
    assert sd["box"].min() > 10 * 1e-4
    env.close()
