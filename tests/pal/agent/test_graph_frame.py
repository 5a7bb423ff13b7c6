"""The objects' sites in the push frame: the graph, its symmetry, its training columns and its refusals."""

import math
from dataclasses import replace

import numpy as np
import pytest
import torch

import models
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
    assert g.parents("pos.object") == ("pos_prev.object", "vel.object")
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


def test_the_push_frame_refuses_what_it_cannot_do():
    env = PushingEnv(camera=True)
    with pytest.raises(ValueError, match="object_frame='push' is for sensed objects; \\['box', 'ball'\\]"):
        Agent(env, pushing_spec(), replace(CONFIG, servo=None), seed=0)  # its objects are perceived
    env.close()
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
