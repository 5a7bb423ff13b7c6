"""Data aggregation: rounds of episode + warm refit, their counts, checkpoints and bad inputs (tiny sizes)."""

from dataclasses import replace

import gymnasium
import numpy as np
import pytest

from pal.agent import Agent, AgentConfig, ModelConfig, PlanConfig, pusher_spec
from pal.agent.aggregate import (
    AgentLearner,
    AggregationConfig,
    Exploration,
    Rollout,
    aggregate,
    episode_seed,
    parameter_digest,
    run_rounds,
)
from pal.agent.config import MODEL_SCHEDULE, PLAN_ACTION, PLAN_SAMPLING


class _Fake:
    """A learner that logs what it is asked to do; its episodes end early after ``short`` steps."""

    def __init__(self, short: int | None = None) -> None:
        self.calls: list[tuple] = []
        self.short = short

    def episode(self, seed: int, steps: int, random: bool, exploration: Exploration | None = None) -> Rollout:
        self.calls.append(("episode", seed, random, exploration))
        n = steps if self.short is None else min(steps, self.short)
        return Rollout(n, {"random": random})

    def refit(self) -> bool:
        self.calls.append(("refit",))
        return sum(c[0] == "refit" for c in self.calls) > 1  # every refit after the first is warm


def test_rounds_count_steps_episodes_and_refits_and_call_checkpoints_once():
    learner = _Fake()
    seen = []
    config = AggregationConfig(rounds=4, episode_steps=10, random_rounds=1, checkpoints=(10, 25, 40))
    result = run_rounds(
        learner, config, seed=3, at_checkpoint=lambda p, c: seen.append((p, c.env_steps)) or p
    )
    c = result.counts
    assert (c.env_steps, c.episodes, c.random_episodes, c.refits, c.warm_refits) == (40, 4, 1, 4, 3)
    assert result.steps == [10, 20, 30, 40]
    # 25 is reached after the third episode (30 steps): each checkpoint once, after its refit
    assert seen == [(10, 10), (25, 30), (40, 40)]
    assert list(result.checkpoints) == [10, 25, 40]
    assert [e["random"] for e in result.episodes] == [
        True,
        False,
        False,
        False,
    ]  # only the first round is random
    # the same seed gives the same episode seeds, another seed others
    seeds = [s for kind, *rest in learner.calls if kind == "episode" for s in rest[:1]]
    assert seeds == [episode_seed(3, r) for r in range(4)]
    again = _Fake()
    run_rounds(again, config, seed=3)
    assert seeds == [s for kind, *rest in again.calls if kind == "episode" for s in rest[:1]]
    assert len(set(seeds)) == 4


def test_babbling_heavy_protocol_refits_only_after_the_last_random_round_and_short_episodes_count_true_steps():
    learner = _Fake(short=7)
    config = AggregationConfig(rounds=5, episode_steps=10, random_rounds=3)
    c = run_rounds(learner, config).counts
    kinds = [k[0] for k in learner.calls]
    assert kinds == ["episode", "episode", "episode", "refit", "episode", "refit", "episode", "refit"]
    assert (c.env_steps, c.episodes, c.random_episodes, c.refits) == (35, 5, 3, 3)


TINY = AgentConfig(
    model=ModelConfig(members=2, hidden=(8,), schedule=replace(MODEL_SCHEDULE, epochs=2, patience=None)),
    plan=PlanConfig(
        action=replace(
            PLAN_ACTION,
            scale=1.0,
            sampling=replace(PLAN_SAMPLING, population=8, elites=2, iterations=1, refine_steps=0),
        ),
        preference="distance",
        effector_weight=0.5,
    ),
    reset_every=None,
    servo=False,
)


@pytest.mark.slow
def test_the_agent_acts_randomly_first_then_with_its_model_and_refits_warm():
    env = gymnasium.make("Pusher-v5")
    agent = Agent(env, pusher_spec(), TINY, seed=0)
    digests = []
    learner = AgentLearner(agent)
    refit = learner.refit

    def spy() -> bool:
        before = parameter_digest(agent.model)
        warm = refit()
        digests.append((before, parameter_digest(agent.model)))
        return warm

    learner.refit = spy
    config = AggregationConfig(rounds=3, episode_steps=4, random_rounds=1, checkpoints=(8,))
    result = run_rounds(learner, config, seed=1, at_checkpoint=lambda p, c: len(agent.history))
    env.close()
    c = result.counts
    assert (c.env_steps, c.episodes, c.random_episodes, c.refits, c.warm_refits) == (12, 3, 1, 3, 2)
    assert len(agent.history) == 12 and result.checkpoints == {8: 8}
    first, *later = result.episodes
    assert first == [None] * 4  # random actions, no decision
    assert all(d.mode == "goal" for e in later for d in e)  # every later step planned with the model
    # each refit starts from the weights the previous one left, and changes them
    for (before, _), (_, after_previous) in zip(digests[1:], digests[:-1], strict=True):
        assert before == after_previous
    assert all(b != a for b, a in digests)


def test_aggregate_runs_the_agent_in_goal_mode():
    env = gymnasium.make("Pusher-v5")
    agent = Agent(env, pusher_spec(), TINY, seed=2)
    result = aggregate(agent, AggregationConfig(rounds=2, episode_steps=2))
    env.close()
    assert result.counts.to_dict() == {
        "env_steps": 4,
        "episodes": 2,
        "random_episodes": 1,
        "branches": 0,
        "branch_steps": 0,
        "refits": 2,
        "warm_refits": 1,
    }
    assert np.isfinite(agent.history.array("act")).all()


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"rounds": 0}, "rounds is 0; aggregation needs at least 1 round"),
        ({"rounds": -2}, "rounds is -2"),
        (
            {"rounds": 10, "episode_steps": 100, "checkpoints": (1500,)},
            "checkpoint 1500 is beyond the step budget 1000",
        ),
        ({"checkpoints": (3000, 1500)}, r"checkpoints \[3000, 1500\] are not strictly increasing"),
        ({"checkpoints": (1500, 1500)}, "not strictly increasing"),
        ({"checkpoints": (0,)}, "checkpoints must be"),
        (
            {"rounds": 11, "episode_steps": 100, "random_rounds": 10, "checkpoints": (100, 1000)},
            "checkpoint 100 comes before the first fit at 1000 steps",
        ),
        ({"rounds": 2, "random_rounds": 3}, "random_rounds must be"),
        ({"episode_steps": 0}, "episode_steps must be"),
        ({"exploration": 0.1}, "exploration must be an Exploration, got float"),
    ],
)
def test_bad_aggregation_settings_name_the_value(kwargs, match):
    with pytest.raises(ValueError, match=match):
        AggregationConfig(**kwargs)


def test_exploration_noise_is_seeded_scaled_to_the_action_range_and_smooth():
    low, high = np.array([-2.0, 0.0]), np.array([2.0, 1.0])
    noise = Exploration(sd=0.1, beta=2.0)
    a = noise.offsets(5, 4000, low, high)
    assert a.shape == (4000, 2)
    assert np.array_equal(a, noise.offsets(5, 4000, low, high))  # the seed alone decides
    assert not np.allclose(a, noise.offsets(6, 4000, low, high))
    np.testing.assert_allclose(
        noise.offsets(5, 4000, 3 * low, 3 * high), 3 * a
    )  # one unit sequence, any bounds
    # unit noise times sd x range: across 400 episodes each step has sd 0.4 and 0.1 (sampling error ~4 %)
    many = np.stack([noise.offsets(s, 50, low, high) for s in range(400)])
    np.testing.assert_allclose(many.std(0).mean(0), [0.4, 0.1], rtol=0.1)
    # beta 2 drifts: successive steps are strongly correlated; white noise is not
    lag1 = lambda x: np.corrcoef(x[:-1], x[1:])[0, 1]  # noqa: E731
    assert lag1(a[:, 0]) > 0.9
    assert abs(lag1(Exploration(sd=0.1, beta=0.0).offsets(5, 4000, low, high)[:, 0])) < 0.1
    assert Exploration().offsets(5, 10, low, high) is None  # sd 0: no noise


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [({"sd": -0.1}, "exploration.sd must be"), ({"beta": -1.0}, "exploration.beta must be")],
)
def test_bad_exploration_settings_name_the_value(kwargs, match):
    with pytest.raises(ValueError, match=match):
        Exploration(**kwargs)
    with pytest.raises(ValueError, match=r"two \(A,\) arrays, got shapes \(2,\) and \(3,\)"):
        Exploration(sd=0.1).offsets(0, 5, np.zeros(2), np.ones(3))


def test_rounds_hand_the_exploration_to_model_episodes():
    learner = _Fake()
    noise = Exploration(sd=0.2)
    run_rounds(learner, AggregationConfig(rounds=2, episode_steps=3, exploration=noise), seed=0)
    assert [c[3] for c in learner.calls if c[0] == "episode"] == [noise, noise]


def test_the_agent_executes_its_plan_plus_the_episode_noise():
    config = AggregationConfig(rounds=2, episode_steps=5, exploration=Exploration(sd=0.05))
    executed = {}
    for label, cfg in (("plain", replace(config, exploration=Exploration())), ("noisy", config)):
        env = gymnasium.make("Pusher-v5")
        agent = Agent(env, pusher_spec(), TINY, seed=4)
        result = aggregate(agent, cfg, seed=9)
        env.close()
        executed[label] = (agent.history.array("act")[5:], np.stack([d.action for d in result.episodes[1]]))
    act, planned = executed["noisy"]
    seed = episode_seed(9, 1)
    expected = np.clip(
        planned + config.exploration.offsets(seed, 5, agent.low, agent.high), agent.low, agent.high
    )
    np.testing.assert_allclose(act, expected, atol=1e-12)
    assert np.abs(act - planned).max() > 0.01  # the noise is really there
    plain_act, plain_planned = executed["plain"]
    np.testing.assert_allclose(plain_act, np.clip(plain_planned, agent.low, agent.high), atol=1e-12)
