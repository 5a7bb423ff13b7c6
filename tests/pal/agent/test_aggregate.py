"""Data aggregation: rounds of episode + warm refit, their counts, checkpoints and bad inputs (tiny sizes)."""

from dataclasses import replace

import gymnasium
import numpy as np
import pytest

from pal.agent import Agent, AgentConfig, ModelConfig, PlanConfig, pusher_spec
from pal.agent.aggregate import (
    AgentLearner,
    AggregationConfig,
    Rollout,
    aggregate,
    parameter_digest,
    run_rounds,
)
from pal.agent.config import MODEL_SCHEDULE, PLAN_ACTION, PLAN_SAMPLING


class _Fake:
    """A learner that logs what it is asked to do; its episodes end early after ``short`` steps."""

    def __init__(self, short: int | None = None) -> None:
        self.calls: list[tuple] = []
        self.short = short

    def episode(self, seed: int, steps: int, random: bool) -> Rollout:
        self.calls.append(("episode", seed, random))
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
    ],
)
def test_bad_aggregation_settings_name_the_value(kwargs, match):
    with pytest.raises(ValueError, match=match):
        AggregationConfig(**kwargs)
