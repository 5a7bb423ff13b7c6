"""The simulator worlds of the query language (determinism, replay, babbling starts), the two
vocabularies, and the LoT experiment's agreement rule and start grades shared by both worlds."""

from __future__ import annotations

import math
from dataclasses import replace

import gymnasium
import numpy as np
import pytest
import torch

from pal.agent import ModelConfig, build_graph, build_model, pusher_spec, pushing_spec
from pal.agent.config import MODEL_SCHEDULE
from pal.experiments.language.lot_play import agree
from pal.language.evaluate import Answer
from pal.language.predicates import literal_grade
from pal.language.signature import UnknownConstantError
from pal.language.sim_worlds import PusherWorld, PushingWorld, pusher_situations, pushing_situations
from pal.language.terms import Literal, atom
from pal.language.vocabularies import pusher_signature, pushing_signature
from pal.language.world import ModelWorld, Situations
from pal.sim.pushing import PushingEnv

TINY_MODEL = ModelConfig(members=1, hidden=(4,), schedule=replace(MODEL_SCHEDULE, epochs=1, patience=None))


@pytest.fixture(scope="module")
def pushing():
    env = PushingEnv()
    values, states = pushing_situations(env, 3, np.random.default_rng(0))
    yield env, Situations({k: values[k] for k in ("q", "ee", "pos.box")}, states)
    env.close()


def test_pushing_world_is_replay_exact(pushing):
    env, situations = pushing
    world = PushingWorld(env)
    gen = torch.Generator().manual_seed(0)
    plan = torch.as_tensor(np.random.default_rng(1).uniform(env.ctrl_low, env.ctrl_high, (3, 2, 2)))
    a, b = world.play(situations, [plan, plan.clone()], 1, gen)
    assert a.shape == (3, 1, 3)
    for name in a.paths:
        assert torch.equal(a.paths[name], b.paths[name]), name
    # the first step equals PushingEnv.replay (mujoco.rollout) from the same state, bit for bit
    for i in range(3):
        replayed = env.replay(situations.states[i], plan[i, :1].numpy())
        for o in env.objects:
            np.testing.assert_array_equal(replayed[o][0, :2], a.paths[f"pos.{o}"][i, 0, 1].numpy())
    # the start is the recorded situation; contact is zero at the start
    torch.testing.assert_close(a.paths["ee"][:, 0, 0], situations.values["ee"], rtol=0, atol=1e-12)
    assert float(a.paths["contact.box"][:, 0, 0].abs().max()) == 0.0


def test_pushing_world_refuses_bad_plans(pushing):
    env, situations = pushing
    world = PushingWorld(env)
    with pytest.raises(ValueError, match="expected finite"):
        world.play(situations, [torch.zeros(2, 1, 2)])
    with pytest.raises(ValueError, match="states=None"):
        world.play(Situations({"q": situations.values["q"]}), [torch.zeros(3, 1, 2)])


def test_pusher_world_is_deterministic():
    env = gymnasium.make("Pusher-v5")
    values, states = pusher_situations(env, 2, np.random.default_rng(0), near_fraction=1.0)
    assert np.all(np.linalg.norm(values["ee"][:, :2] - values["pos.object"][:, :2], axis=1) < 0.13)
    world = PusherWorld(env)
    situations = Situations({"q": values["q"]}, states)
    plan = torch.as_tensor(np.random.default_rng(2).uniform(-2, 2, (2, 4, 7)))
    a = world.play(situations, [plan])[0]
    b = world.play(situations, [plan])[0]
    for name in a.paths:
        assert torch.equal(a.paths[name], b.paths[name]), name
    np.testing.assert_array_equal(a.paths["q"][:, 0, 0].numpy(), values["q"])
    env.close()


def test_vocabularies_bind_model_variables_and_refuse_unknown_constants():
    s = pushing_signature()
    assert s.support(atom("near", "hand", "box")) == ("ee", "pos.box")
    assert s.support(atom("touch", "hand", "ball")) == ("contact.ball",)
    with pytest.raises(UnknownConstantError, match="cup"):
        s.predicate(atom("near", "hand", "cup"))
    p = pusher_signature()
    assert p.support(atom("moving", "object")) == ("pos.object",)
    assert p.support(atom("near", "object", "goal")) == ("pos.object", "goal.object")
    with pytest.raises(UnknownConstantError, match="box"):
        p.action(atom("reach", "fingertip", "box"))


def _velocity(env, state):
    obs, _ = env.reset(options={"state": state})
    return float(np.abs(obs[2:4]).max())


def test_babbling_starts_move_the_arm_and_replay_exactly(pushing):
    env, settled = pushing
    values, states = pushing_situations(env, 4, np.random.default_rng(0), babble=(0.5, 0.5))
    # the settled draws rest; one babbling step later the arm moves (rad/s) as in the babbling data
    assert max(_velocity(env, s) for s in settled.states) < 0.05
    assert max(_velocity(env, s) for s in states) > 0.05
    world = PushingWorld(env)
    for i, s in enumerate(states):
        start = world.restore(s)
        for name in ("q", "ee", "pos.box", "pos.ball"):
            np.testing.assert_allclose(start[name], values[name][i], rtol=0, atol=1e-12, err_msg=name)
    with pytest.raises(ValueError, match="babble must be"):
        pushing_situations(env, 1, np.random.default_rng(0), babble=(1.5, 0.5))


def test_pusher_babbling_starts_have_the_object_at_rest_near_the_tip():
    env = gymnasium.make("Pusher-v5")
    values, states = pusher_situations(
        env, 4, np.random.default_rng(3), near_fraction=1.0, near_radius=(0.05, 0.1), babble_steps=30
    )
    nq = env.unwrapped.model.nq
    assert np.abs(states[:, nq + 7 : nq + 9]).max() == 0.0  # the object's slide velocities
    assert np.abs(states[:, nq : nq + 7]).max() > 0.1  # the arm moves after babbling
    d = np.linalg.norm(values["ee"][:, :2] - values["pos.object"][:, :2], axis=1)
    assert np.all((d > 0.05 - 1e-9) & (d < 0.1 + 1e-9)), d
    np.testing.assert_array_equal(values["dpos.object"], 0.0)
    again, _ = pusher_situations(
        env, 4, np.random.default_rng(3), near_fraction=1.0, near_radius=(0.05, 0.1), babble_steps=30
    )
    np.testing.assert_array_equal(again["q"], values["q"])
    with pytest.raises(ValueError, match="babble_steps"):
        pusher_situations(env, 1, np.random.default_rng(0), babble_steps=-1)
    env.close()


def _start_grades(sig, literals, outcomes):
    return [[literal_grade(Literal(atom(*a), time="start"), sig, o) for a in literals] for o in outcomes]


def test_start_grades_and_held_goal_are_the_same_in_both_worlds(pushing):
    """Evidence is graded on the start values: the model world's and the replayed simulator's coincide."""
    env, _ = pushing
    values, states = pushing_situations(env, 3, np.random.default_rng(5), babble=(0.5, 0.5))
    spec = pushing_spec()
    model = build_model(spec, build_graph(spec, (env.ctrl_low, env.ctrl_high)), TINY_MODEL, seed=0).double()
    sit = Situations(values, states)
    plan = torch.as_tensor(values["q"])[:, None, :]
    sig = pushing_signature()
    literals = [("near", "hand", "box"), ("left_of", "hand", "box"), ("near", "hand", "ball")]
    m = ModelWorld(model).play(sit, [plan], 2, torch.Generator().manual_seed(0))
    s = PushingWorld(env).play(sit, [plan])
    for gm, gs in zip(*_start_grades(sig, literals, [m[0], s[0]]), strict=True):
        torch.testing.assert_close(gm, gs.expand_as(gm), rtol=0, atol=1e-9)

    penv = gymnasium.make("Pusher-v5")
    values, states = pusher_situations(penv, 3, np.random.default_rng(6), babble_steps=10)
    spec = pusher_spec()
    bounds = (penv.action_space.low.astype(np.float64), penv.action_space.high.astype(np.float64))
    model = build_model(spec, build_graph(spec, bounds), TINY_MODEL, seed=0).double()
    sit = Situations({k: v for k, v in values.items() if k in model.graph or k == "goal.object"}, states)
    plan = torch.zeros(3, 4, 7, dtype=torch.float64)
    sig = pusher_signature()
    with pytest.raises(ValueError, match="goal.object"):
        ModelWorld(model).play(sit, [plan], 1, torch.Generator())
    m = ModelWorld(model, held=("goal.object",)).play(sit, [plan], 2, torch.Generator().manual_seed(0))
    s = PusherWorld(penv).play(sit, [plan])
    literals = [("near", "fingertip", "object"), ("left_of", "fingertip", "goal"), ("near", "object", "goal")]
    for gm, gs in zip(*_start_grades(sig, literals, [m[0], s[0]]), strict=True):
        torch.testing.assert_close(gm, gs.expand_as(gm), rtol=0, atol=1e-9)
    # the goal marker does not move in the simulator; the model world holds it
    goal_sim = s[0].paths["goal.object"]
    torch.testing.assert_close(goal_sim, goal_sim[:, :, :1].expand_as(goal_sim), rtol=0, atol=1e-12)
    torch.testing.assert_close(m[0].paths["goal.object"], goal_sim.expand(3, 2, 5, 3), rtol=0, atol=1e-12)
    penv.close()


def _answer(p: float, se: float) -> Answer:
    return Answer(p, se, 10, 1, 10.0)


@pytest.mark.parametrize(
    ("model", "sim", "expected"),
    [
        ((0.50, 0.01), (0.54, 0.01), True),  # within the tolerance
        ((0.50, 0.10), (0.68, 0.10), True),  # 0.18 apart, each inside the other's ±0.196
        ((0.50, 0.10), (0.68, 0.01), False),  # the model's interval holds 0.68, the simulator's not 0.5
        ((0.50, 0.01), (0.60, 0.01), False),  # 0.1 apart, tight intervals
        ((0.373, 0.0), (0.373, 0.0), True),  # equal, degenerate intervals
    ],
)
def test_agreement_rule(model, sim, expected):
    assert agree(_answer(*model), _answer(*sim), 0.05) is expected


def test_the_grounding_floor_sets_how_moving_a_resting_object_is():
    """moving(o) = Phi((|dp| - v0) / (v0 / 4 + sqrt(2) sigma)): at rest 0.374 with the 1 cm floor, 0.030 with 1 mm."""
    from pal.perception.grounding import GroundingConfig

    rest = {"pos.box": torch.zeros(3, 2, 2, dtype=torch.float64)}  # (N, window + 1, d): no motion
    lit = Literal(atom("moving", "box"), time="end")
    coarse = literal_grade(lit, pushing_signature(), rest)
    fine = literal_grade(lit, pushing_signature(grounding=GroundingConfig(position_floor=0.001)), rest)
    v0 = 0.005
    expected = [0.5 * math.erfc(v0 / (0.25 * v0 + math.sqrt(2) * s) / math.sqrt(2)) for s in (0.01, 0.001)]
    torch.testing.assert_close(coarse, torch.full((3,), expected[0], dtype=torch.float64), rtol=0, atol=1e-9)
    torch.testing.assert_close(fine, torch.full((3,), expected[1], dtype=torch.float64), rtol=0, atol=1e-9)
    assert expected[0] > 0.35 and expected[1] < 0.05
    from pal.experiments.language.lot import Config

    with pytest.raises(ValueError, match="position_sigma"):
        Config(position_sigma=0.0)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"horizon": 0}, "horizon must be None or an int >= 1"),
        ({"horizon": 1.5}, "horizon must be None or an int >= 1"),
        ({"push_distance": -1.0}, "push_distance must be > 0"),
        ({"push_distance": float("nan")}, "push_distance must be finite"),
    ],
)
def test_vocabularies_refuse_bad_settings(kwargs, message):
    for make in (pushing_signature, pusher_signature):
        with pytest.raises(ValueError, match=message):
            make(**kwargs)


def test_a_query_needs_a_world():
    from pal.language import P

    sit = Situations({"q": torch.zeros(2, 2, dtype=torch.float64)})
    with pytest.raises(TypeError, match="world must be a World .*got str"):
        P("P(near(hand, box))", pushing_signature(), "simulator", sit)
