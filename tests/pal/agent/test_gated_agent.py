"""The gated displacement form: a contact switch per object, on the pushing world and Pusher-v5."""

import warnings
from dataclasses import replace

import gymnasium
import numpy as np
import pytest
import torch

from inference import SVIOptions, infer_state
from models import BernoulliMechanism, GatedMechanism
from pal.agent import Agent, ModelConfig, blanket, build_graph, build_model, pusher_spec, pushing_spec
from pal.agent.graph import MOVED_SIGMAS, contact_rule
from pal.agent.history import contact_label
from pal.sim.pushing import PushingEnv

from .test_agent import TINY, short_run

GATED = replace(TINY, model=replace(TINY.model, displacement="gated"))
BOUNDS = (-np.ones(7), np.ones(7))


def test_the_displacement_form_is_checked_and_gated_by_default():
    assert ModelConfig().displacement == "gated"
    assert "contact.object" in build_graph(pusher_spec(), BOUNDS).names
    with pytest.raises(
        ValueError, match="displacement 'switched' unknown; expected one of \\['smooth', 'gated'\\]"
    ):
        ModelConfig(displacement="switched")
    with pytest.raises(ValueError, match="displacement 'switched' unknown"):
        build_graph(pusher_spec(), BOUNDS, displacement="switched")


def test_the_gated_graph_gives_every_object_a_bernoulli_switch_and_a_floor():
    spec = pusher_spec()  # no touch sensing: the smooth form has no contact site
    assert "contact.object" not in build_graph(spec, BOUNDS, displacement="smooth").names
    config = ModelConfig(hidden=(8,), members=2, displacement="gated")
    graph = build_graph(spec, BOUNDS, displacement="gated")
    assert graph.parents("contact.object") == ("rel_prev.object", "rel.object")
    assert "contact.object" in graph.parents("dpos.object")
    model = build_model(spec, graph, config, seed=0)
    switch, dpos = model.mechanism("contact.object"), model.mechanism("dpos.object")
    assert isinstance(switch, BernoulliMechanism) and isinstance(dpos, GatedMechanism)
    assert dpos.size == 2 and torch.allclose(dpos.floor, torch.full((3,), config.position_sigma))
    assert contact_rule(spec, config) == ("moved", MOVED_SIGMAS * config.position_sigma)
    assert contact_rule(pushing_spec(), config) == ("touch", 0.0)
    assert contact_rule(spec, ModelConfig(displacement="smooth")) == ("strength", 0.0)


def test_contact_labels_follow_the_touch_or_the_moved_rule():
    touch = np.array([0.0, 0.2, 1.0, 0.0])
    dpos = np.array([[0.0, 0.0], [0.0, 0.0], [0.002, 0.0], [0.003, 0.004]])
    np.testing.assert_array_equal(contact_label(touch, dpos, "strength")[:, 0], touch)
    np.testing.assert_array_equal(contact_label(touch, dpos, "touch")[:, 0], [0, 1, 1, 0])
    np.testing.assert_array_equal(contact_label(touch, dpos, "moved", 0.003)[:, 0], [0, 0, 0, 1])
    with pytest.raises(ValueError, match="contact rule 'near' unknown"):
        contact_label(touch, dpos, "near")
    with pytest.raises(ValueError, match="floor must be finite and >= 0, got -1"):
        contact_label(touch, dpos, "moved", -1)


@pytest.mark.filterwarnings("ignore::inference.PoorPosteriorWarning")
@pytest.mark.slow
def test_the_gated_agent_runs_the_pushing_world_deterministically():
    env = PushingEnv(camera=True)
    try:
        a, da = short_run(env, 0, GATED, babble=6)
        b, db = short_run(env, 0, GATED, babble=6)
    finally:
        env.close()
    assert isinstance(a.model.mechanism("dpos.box"), GatedMechanism)
    assert (a.history.array("touch")[:6] > 0).any()  # the on branches were fitted on touched rows
    for x, y in zip(da, db, strict=True):
        np.testing.assert_array_equal(x.action, y.action)
    est = a.history.array("est")
    np.testing.assert_array_equal(est, b.history.array("est"))
    assert np.isfinite(est[np.isfinite(a.history.array("meas"))]).all()
    _, objects = a.history.columns(contact="touch")
    for cols in objects.values():
        assert all(np.isfinite(v).all() for v in cols.values())
        assert set(np.unique(cols["contact.box" if "contact.box" in cols else "contact.ball"])) <= {0.0, 1.0}


def _pusher_run(seed):
    env = gymnasium.make("Pusher-v5")
    try:
        agent = Agent(env, pusher_spec(), GATED, seed=seed)
        decisions = agent.run(6, "babble")
        agent.refit()
        decisions += agent.run(2, "goal")
    finally:
        env.close()
    return agent, decisions


@pytest.mark.slow
def test_the_gated_agent_runs_a_tiny_pusher_episode_deterministically():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        a, da = _pusher_run(3)
        b, db = _pusher_run(3)
    assert isinstance(a.model.mechanism("dpos.object"), GatedMechanism)
    assert isinstance(a.model.mechanism("contact.object"), BernoulliMechanism)
    for x, y in zip(da, db, strict=True):
        assert np.isfinite(x.action).all()
        np.testing.assert_array_equal(x.action, y.action)
    np.testing.assert_array_equal(a.history.array("est"), b.history.array("est"))
    assert np.isfinite(a.history.array("est")).all()
    # the moved rule labels the switch from the data (no touch sensor)
    _, objects = a.history.columns(contact="moved", floor=MOVED_SIGMAS * GATED.model.position_sigma)
    labels = objects["object"]["contact.object"]
    moved = np.linalg.norm(objects["object"]["dpos.object"], axis=1) > 0.003
    np.testing.assert_array_equal(labels[:, 0], moved.astype(np.float32))


def test_state_inference_enumerates_a_latent_switch_without_touch_sensing():
    spec = pusher_spec()
    config = ModelConfig(hidden=(8,), members=2, displacement="gated")
    model = build_model(spec, build_graph(spec, BOUNDS, displacement="gated"), config, seed=0)
    program = blanket(model, ("object",), observed_contact=False)
    assert "contact.object" not in program.graph.roots
    p = np.array([[0.5, -0.2, -0.3]])
    obs = {
        "pos_prev.object": p,
        "vel_prev.object": np.zeros((1, 3)),
        "rel_prev.object": np.array([[0.05, 0.0, 0.0]]),
        "rel.object": np.array([[0.02, 0.0, 0.0]]),
    }
    svi = {"num_steps": 100, "num_samples": 64, "options": SVIOptions(lr=0.01, init_scale=5e-4), "seed": 0}
    moved = infer_state(program, {**obs, "pos.object": p + 0.01}, **svi)
    rest = infer_state(program, {**obs, "pos.object": p}, **svi)
    # 1 cm is 10 floors away from rest: on; no motion at all: off
    assert float(moved.mean["contact.object"]) == 1.0 and float(rest.mean["contact.object"]) == 0.0
