"""The simulator worlds of the query language (determinism, replay) and the two vocabularies."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest
import torch

from pal.language.signature import UnknownConstantError
from pal.language.sim_worlds import PusherWorld, PushingWorld, pusher_situations, pushing_situations
from pal.language.terms import atom
from pal.language.vocabularies import pusher_signature, pushing_signature
from pal.language.world import Situations
from pal.sim.pushing import PushingEnv


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
    with pytest.raises(UnknownConstantError, match="box"):
        p.action(atom("reach", "fingertip", "box"))
