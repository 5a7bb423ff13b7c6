"""Curiosity that seeks contact: the action-specific gate, novelty, the fall-back threshold, the refit interval."""

from dataclasses import replace

import numpy as np
import pytest
import torch

from models import BernoulliMechanism, LinearMechanism
from pal.agent import (
    Agent,
    AgentConfig,
    CuriosityConfig,
    ModelConfig,
    build_graph,
    build_model,
    pusher_spec,
    pushing_spec,
)
from pal.agent.config import CURIOSITY_SAMPLING
from pal.agent.curiosity import GridCuriosity
from pal.agent.explore import at_limit, contact_search, novelty, push_counts, step_gate
from pal.sim.pushing import PushingEnv


def _model():
    """Pusher's graph, gated: the hand moves by 0.1 x the first three torques, contact when it nears +x of the object."""
    spec = pusher_spec()
    graph = build_graph(spec, (-2 * np.ones(7), 2 * np.ones(7)), displacement="gated")
    w_ee = torch.zeros(3, 14)
    w_ee[:, 7:10] = 0.1 * torch.eye(3)  # parents: q_prev (7), dq (7)
    w_c = torch.zeros(6)
    w_c[3] = -40.0  # parents: rel_prev (3), rel (3): logit = 2 - 40 rel_x
    known = {
        "dq": LinearMechanism.from_coefficients(
            torch.cat([torch.eye(7), torch.zeros(7, 14)], 1), sigma=0.001
        ),
        "dee": LinearMechanism.from_coefficients(w_ee, sigma=0.001),
        "contact.object": BernoulliMechanism.from_coefficients(w_c, 2.0),
    }
    config = ModelConfig(members=3, hidden=(8,))
    return spec, graph, build_model(spec, graph, config, mechanisms=known, seed=0)


def _state(graph, r=1):
    state = {k: torch.zeros(r, graph[k].dim, dtype=torch.float64) for k in graph.roots if k != "act"}
    state["ee_prev"][:, 0] = 0.2  # the hand 20 cm on the +x side of the object
    return state


def test_the_gate_is_higher_for_an_action_that_brings_the_hand_onto_the_object():
    _, graph, model = _model()
    state = {k: v.to(model.dtype) for k, v in _state(graph, 2).items()}
    act = torch.zeros(2, 7, dtype=model.dtype)
    act[0, 0], act[1, 0] = -2.0, 2.0  # onto the object (rel_x 0) / away (rel_x 0.4)
    g = step_gate(model, state, act, ("object",), 0.02)
    assert g.p_on["object"][0] > 0.8 > 0.01 > g.p_on["object"][1]
    assert g.spread["object"].min() > 0  # the random members' on branches disagree
    assert g.gate("object")[0] > 10 * g.gate("object")[1]


def test_the_search_travels_to_the_object_and_reports_its_information():
    _, graph, model = _model()
    belief = {k: v[0].numpy() for k, v in _state(graph).items()}
    grids = {"object": GridCuriosity((-1, -1), (1, 1), (4, 4))}
    config = CuriosityConfig(horizon=5, sampling=replace(CURIOSITY_SAMPLING, population=32, iterations=2))
    found = contact_search(
        model, belief, np.zeros(7), ("object",), grids, config, 0.02, torch.Generator().manual_seed(0)
    )
    assert found.sequence.shape == (5, 7) and found.information > 0
    assert found.sequence[:, 0].sum() < -1.0  # the hand is sent towards -x, onto the object
    low, high = -2 * np.ones(7), 2 * np.ones(7)
    assert not at_limit(found.sequence, low, high).all()


def test_novelty_decays_with_pushes_into_a_cell():
    grid = GridCuriosity((0, 0), (1, 1), (2, 2))
    here = torch.tensor([[0.2, 0.2], [0.8, 0.8]])
    torch.testing.assert_close(novelty(grid, here), torch.ones(2))
    prev = np.array([[0.1, 0.2], [0.2, 0.2], [0.2, 0.1]])
    after = np.array([[0.2, 0.2], [0.2, 0.2], [0.25, 0.25]])  # moved 10 cm, rested, moved 16 cm
    push_counts(prev, after, grid, moved=0.005)
    assert grid.counts_.sum() == 2  # the resting step is not a push
    nu = novelty(grid, here)
    torch.testing.assert_close(nu, torch.tensor([1 / np.sqrt(3), 1.0], dtype=nu.dtype), rtol=0, atol=1e-6)
    push_counts(prev[:1], after[:1], grid, moved=0.005)
    assert novelty(grid, here)[0] < nu[0]


@pytest.mark.parametrize("bad", [0, -3, 2.5, True])
def test_a_curiosity_refit_interval_below_one_is_refused(bad):
    with pytest.raises(ValueError, match=r"curiosity\.refit_every is .*int N >= 1"):
        CuriosityConfig(refit_every=bad)
    assert CuriosityConfig(refit_every=1).refit_every == 1


def test_low_information_steps_fall_back_to_babbling():
    env = PushingEnv(camera=True, camera_size=(160, 120))
    tiny = AgentConfig(
        model=ModelConfig(
            members=2, hidden=(8,), schedule=replace(ModelConfig().schedule, epochs=2, patience=None)
        ),
        curiosity=CuriosityConfig(
            horizon=2, sampling=replace(CURIOSITY_SAMPLING, population=4, elites=2, iterations=1)
        ),
        reset_every=None,
    )
    try:
        agent = Agent(env, pushing_spec(), tiny, seed=0)
        agent.run(12, "babble")
        agent.refit()
        always = replace(tiny, curiosity=replace(tiny.curiosity, min_score=1e9))
        agent.config = always
        d = agent.decide("curious")
        assert d.mode == "babble" and d.score < 1e9 and set(d.diagnostics) == {"gate", "p_on", "influence"}
        agent.config = replace(tiny, curiosity=replace(tiny.curiosity, min_score=0.0))
        assert agent.decide("curious").mode == "curious"
    finally:
        env.close()
