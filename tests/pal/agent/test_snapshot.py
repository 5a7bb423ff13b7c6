"""Agent snapshots: a stopped aggregation run restored from its snapshot goes on exactly as one never stopped."""

from __future__ import annotations

import copy
from dataclasses import replace

import numpy as np
import pytest
import torch

from pal.agent import Agent, AgentConfig, pusher_spec
from pal.agent.aggregate import AgentLearner, RoundsResult, run_rounds
from pal.agent.snapshot import restore_agent, save_agent
from pal.experiments.closed_loop import pusher
from pal.experiments.closed_loop.pusher_runs import agent_rollout, training_env
from pal.io.files import FileFormatError

TINY = pusher.TINY
ROUNDS = replace(TINY.aggregation, rounds=5, checkpoints=(6,))
CONFIG = AgentConfig(
    model=TINY.model, plan=TINY.plan, correction=TINY.correction, reset_every=None, servo=False
)


class Stopped(Exception):
    """Raised by the test's hook to stop a run right after its snapshot."""


def agent(config: AgentConfig = CONFIG) -> Agent:
    return Agent(training_env(), pusher_spec(), config, seed=0)


def rounds(learner: Agent, **kwargs) -> RoundsResult:
    episode = agent_rollout(TINY.plan.action.horizon)
    return run_rounds(
        AgentLearner(learner, episode), ROUNDS, seed=0, at_checkpoint=lambda p, c: c.to_dict(), **kwargs
    )


def stopped_run(path) -> tuple[RoundsResult, Agent]:
    """A run snapshotted after every round and stopped after the round of its first checkpoint."""
    seen: dict[str, RoundsResult] = {}
    stopped = agent()

    def snapshot(result: RoundsResult) -> None:
        save_agent(stopped, path, {"round": result.counts.episodes})
        seen["result"] = copy.deepcopy(result)
        if result.checkpoints:
            raise Stopped

    with pytest.raises(Stopped):
        rounds(stopped, after_round=snapshot)
    return seen["result"], stopped


def test_a_restored_run_goes_on_exactly_as_one_never_stopped(tmp_path):
    whole = agent()
    expected = rounds(whole)
    partial, _ = stopped_run(tmp_path / "snap.npz")
    assert 0 < partial.counts.episodes < ROUNDS.rounds and set(partial.checkpoints) == {6}
    resumed = agent()
    assert restore_agent(resumed, tmp_path / "snap.npz") == {"round": partial.counts.episodes}
    assert len(resumed.history) == partial.counts.env_steps and resumed.fitted
    result = rounds(resumed, resume=partial)
    assert result.counts == expected.counts and result.steps == expected.steps
    assert result.checkpoints == expected.checkpoints
    a, b = whole.model.state_dict(), resumed.model.state_dict()
    assert set(a) == set(b) and all(torch.equal(a[k], b[k]) for k in a)
    ha, hb = whole.history.arrays(), resumed.history.arrays()
    assert set(ha) == set(hb) and all(np.array_equal(ha[k], hb[k], equal_nan=True) for k in ha)
    assert whole.rng.bit_generator.state == resumed.rng.bit_generator.state
    assert whole.learner.monitor is not None and resumed.learner.monitor is not None
    assert whole.learner.monitor.levels == resumed.learner.monitor.levels
    assert (whole.episode, whole.steps) == (resumed.episode, resumed.steps)


def test_a_snapshot_of_another_model_is_refused_and_the_agent_left_as_it_was(tmp_path):
    _, stopped = stopped_run(tmp_path / "snap.npz")
    wider = agent(replace(CONFIG, model=replace(TINY.model, hidden=(9,))))
    before = {k: v.clone() for k, v in wider.model.state_dict().items()}
    with pytest.raises(FileFormatError, match=r"snap\.npz.*differ in shape"):
        restore_agent(wider, tmp_path / "snap.npz")
    assert all(torch.equal(before[k], v) for k, v in wider.model.state_dict().items())
    assert len(wider.history) == 0 and not wider.fitted
    fewer = agent(replace(CONFIG, model=replace(TINY.model, members=3)))
    with pytest.raises(FileFormatError, match="does not fit the agent's: missing"):
        restore_agent(fewer, tmp_path / "snap.npz")
    with pytest.raises(FileFormatError):
        restore_agent(agent(), tmp_path / "none.npz")
    next(iter(stopped.model.parameters())).data.fill_(float("nan"))
    with pytest.raises(ValueError, match="NaN/inf"):
        save_agent(stopped, tmp_path / "broken.npz")
    assert not (tmp_path / "broken.npz").exists()


def test_a_resume_that_does_not_fit_the_rounds_is_refused(tmp_path):
    partial, _ = stopped_run(tmp_path / "snap.npz")
    short = replace(partial, steps=partial.steps[:-1])
    with pytest.raises(ValueError, match="step counts"):
        rounds(agent(), resume=short)
    with pytest.raises(ValueError, match="config.rounds = 1"):
        run_rounds(AgentLearner(agent()), replace(ROUNDS, rounds=1, checkpoints=()), resume=partial)
