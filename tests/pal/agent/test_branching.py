"""Branching in aggregation: perturbed continuations from saved states, their counts, actions and bad input."""

import numpy as np
import pytest

from pal.agent import Agent, pusher_spec
from pal.agent.aggregate import (
    AgentLearner,
    AggregationConfig,
    Branching,
    Exploration,
    Rollout,
    branch,
    episode_seed,
    run_rounds,
)
from pal.agent.exploration import branch_seed
from pal.baselines.pets import BaselineConfig
from pal.baselines.pets_aggregate import PetsLearner
from pal.experiments.closed_loop import pusher
from pal.experiments.closed_loop.pusher_runs import step_cost, training_env
from tests.pal.agent.test_aggregate import TINY

LOW, HIGH = -np.ones(2), np.ones(2)


class _Brancher:
    """A learner whose episodes carry a trace (state t = [t], actions ramp) and that logs its branches."""

    low, high = LOW, HIGH

    def __init__(self) -> None:
        self.branches: list[tuple[int, np.ndarray, np.ndarray]] = []
        self.episodes: list[bool] = []

    def episode(self, seed: int, steps: int, random: bool, exploration: Exploration | None = None) -> Rollout:
        self.episodes.append(random)
        states = np.arange(steps, dtype=float)[:, None]
        actions = np.linspace(-0.9, 0.9, 2 * steps).reshape(steps, 2)
        return Rollout(steps, {"seed": seed}, states, actions)

    def refit(self) -> bool:
        return True

    def branch(self, seed: int, state: np.ndarray, actions: np.ndarray) -> int:
        self.branches.append((seed, state, actions))
        return len(actions)


def test_model_episodes_branch_from_their_states_with_seeded_noise_and_the_steps_count():
    b = Branching(every=4, per_state=2, steps=3, noise=Exploration(sd=0.1))
    config = AggregationConfig(rounds=3, episode_steps=10, random_rounds=1, branching=b, checkpoints=(54,))
    assert config.budget == 30 + 2 * 2 * 2 * 3  # two model episodes, starts 0 and 4, two branches each
    learner = _Brancher()
    result = run_rounds(learner, config, seed=5, at_checkpoint=lambda p, c: c.env_steps)
    c = result.counts
    assert (c.env_steps, c.episodes, c.branches, c.branch_steps) == (54, 3, 8, 24)
    assert result.steps == [10, 32, 54] and result.checkpoints == {54: 54}
    first = learner.branches[0]
    assert [s for s, *_ in learner.branches] == [episode_seed(5, 1)] * 4 + [episode_seed(5, 2)] * 4
    assert [float(st[0]) for _, st, _ in learner.branches[:4]] == [0, 0, 4, 4]  # the states at the starts
    taken = np.linspace(-0.9, 0.9, 20).reshape(10, 2)
    for (seed, _, actions), (t, k) in zip(
        learner.branches[:4], [(0, 0), (0, 1), (4, 0), (4, 1)], strict=True
    ):
        noise = b.noise.offsets(branch_seed(seed, t, k), 3, LOW, HIGH)
        np.testing.assert_allclose(actions, np.clip(taken[t : t + 3] + noise, LOW, HIGH), atol=0)
    assert not np.allclose(first[2], learner.branches[1][2])  # each branch its own noise
    assert np.abs(first[2]).max() <= 1.0  # clipped to the bounds


def test_branching_is_refused_without_a_learner_or_trace_that_supports_it():
    class _Plain:
        def episode(self, seed, steps, random, exploration=None):
            return Rollout(steps)

        def refit(self):
            return False

    config = AggregationConfig(rounds=2, episode_steps=4, branching=Branching(every=2, per_state=1, steps=2))
    with pytest.raises(ValueError, match="branching.per_state is 1 but _Plain cannot branch"):
        run_rounds(_Plain(), config)
    with pytest.raises(ValueError, match="wrap the learner's environment in pal.sim.restore.StartFromState"):
        branch(_Brancher(), 0, Rollout(4), config.branching)
    with pytest.raises(
        ValueError, match=r"branch from step 3 needs 2 actions of a \(T, A\) array, got shape \(4, 2\)"
    ):
        Branching(per_state=1, steps=2).actions(0, 3, 0, np.zeros((4, 2)), LOW, HIGH)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"every": 0}, "branching.every must be"),
        ({"per_state": -1}, "branching.per_state must be"),
        ({"steps": 0}, "branching.steps must be"),
        ({"noise": 0.1}, "branching.noise must be an Exploration, got float"),
    ],
)
def test_bad_branching_settings_name_the_value(kwargs, match):
    with pytest.raises(ValueError, match=match):
        Branching(**kwargs)
    with pytest.raises(ValueError, match="branching must be a Branching, got int"):
        AggregationConfig(branching=3)


def test_branching_off_takes_no_steps_and_short_episodes_have_no_starts():
    assert Branching().steps_per_episode(100) == 0 and list(Branching().starts(100)) == []
    b = Branching(every=10, per_state=2, steps=25)
    assert list(b.starts(100)) == [0, 10, 20, 30, 40, 50, 60, 70] and b.steps_per_episode(100) == 400
    assert list(b.starts(20)) == []


@pytest.mark.slow
def test_the_agent_branches_from_its_own_pusher_episodes():
    env = training_env()
    agent = Agent(env, pusher_spec(), TINY, seed=3)
    b = Branching(every=2, per_state=1, steps=2, noise=Exploration(sd=0.05))
    config = AggregationConfig(rounds=2, episode_steps=4, branching=b)
    result = run_rounds(AgentLearner(agent), config, seed=2)
    assert (result.counts.env_steps, result.counts.branches) == (12, 2)
    assert len(agent.history) == 12
    act, q_prev = agent.history.array("act"), agent.history.array("q_prev")
    model_episode = slice(4, 8)
    seed = episode_seed(2, 1)
    for i, t in enumerate((0, 2)):
        expected = b.actions(seed, t, 0, act[model_episode], agent.low, agent.high)
        np.testing.assert_allclose(act[8 + 2 * i : 10 + 2 * i], expected, atol=1e-12)
        # the branch starts where the episode was at step t
        np.testing.assert_allclose(q_prev[8 + 2 * i], q_prev[4 + t], atol=1e-9)
    env.close()


def test_the_baseline_branches_from_its_own_episodes():
    plan = pusher.TINY.plan
    env = training_env()
    learner = PetsLearner(
        env, BaselineConfig(members=2, hidden=(8,), epochs=1), plan, step_cost(plan), seed=0
    )
    b = Branching(every=2, per_state=2, steps=2)
    result = run_rounds(learner, AggregationConfig(rounds=2, episode_steps=4, branching=b), seed=0)
    env.close()
    assert (result.counts.env_steps, result.counts.branches, result.counts.branch_steps) == (16, 4, 8)
    obs = np.stack(learner.data[0])
    assert len(obs) == 16
    episode = result.episodes[1].observations
    for j, t in enumerate((0, 0, 2, 2)):  # each branch starts from the episode's state at its start
        np.testing.assert_allclose(obs[8 + 2 * j, :14], episode[t, :14], atol=1e-9)
