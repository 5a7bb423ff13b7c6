"""One seed of the ``pusher`` experiment: both learners' aggregation rounds, scored at the checkpoints.

See :mod:`pal.experiments.closed_loop.pusher` for the protocol. The agent is evaluated by a
second :class:`pal.agent.Agent` on its own environment that shares the learner's current world
model, so evaluation episodes never enter the learner's data; the baseline is evaluated with
its current ensemble on its own environment, without recording.
"""

from __future__ import annotations

import logging
from typing import Any

import gymnasium
import numpy as np

from pal.agent import Agent, AgentConfig, pusher_spec
from pal.agent.aggregate import AgentLearner, Counts, derived_seed, run_rounds
from pal.baselines.pets_aggregate import PetsLearner
from pal.experiments.closed_loop.pusher_ranking import Probe, pal_predictor, pets_predictor, probes, score
from pal.experiments.closed_loop.pusher_runs import (
    ENV_ID,
    MOVED,
    Episode,
    agent_episode,
    agent_episodes_together,
    agent_rollout,
    evaluation_seeds,
    pets_record,
    random_episode,
    simulator_episode,
    step_cost,
    training_env,
)

__all__ = ["one_seed", "run_part"]

log = logging.getLogger(__name__)


def _log_point(name: str, seed: int, point: int, counts: Counts, episodes: list[Episode]) -> None:
    log.info(
        "pusher seed %d %s at %d steps (%s): final %.3f m, moved %d/%d, min tip-object %.3f m",
        seed,
        name,
        point,
        counts,
        float(np.mean([e.final_planar for e in episodes])),
        sum(e.moved > MOVED for e in episodes),
        len(episodes),
        float(np.median([e.min_tip_object for e in episodes])),
    )


def _pal(
    config: Any, seed: int, goals: list[int], found: list[Probe] | None = None, resume: Any = None
) -> dict[str, Any]:
    """The agent's rounds and its checkpoint evaluations (``resume``: see :func:`run_part`)."""
    cfg = AgentConfig(
        model=config.model, plan=config.plan, correction=config.correction, reset_every=None, servo=False
    )
    steps, h = config.aggregation.episode_steps, config.plan.action.horizon
    env, eval_env = training_env(), gymnasium.make(ENV_ID)
    agent = Agent(env, pusher_spec(), cfg, seed=seed)

    def evaluate(point: int, counts: Counts) -> dict[str, Any]:
        if config.lockstep:  # one judge per goal, their plans made together
            envs = [gymnasium.make(ENV_ID) for _ in goals]
            judges = [
                Agent(e, pusher_spec(), cfg, seed=derived_seed(seed, 92, point, g), model=agent.model)
                for g, e in enumerate(envs)
            ]
            episodes = agent_episodes_together(judges, goals, steps, h)
            for e in envs:
                e.close()
        else:
            judge = Agent(eval_env, pusher_spec(), cfg, seed=derived_seed(seed, 92, point), model=agent.model)
            episodes = [agent_episode(judge, s, steps, h) for s in goals]
        _log_point("pal", seed, point, counts, episodes)
        ranking = (
            score(found, pal_predictor(agent.model, config.plan), config.plan)
            if found and agent.fitted
            else None
        )
        return {"counts": counts.to_dict(), "episodes": episodes, "ranking": ranking}

    start = None if resume is None else resume.restore(agent)
    result = run_rounds(
        AgentLearner(agent, agent_rollout(h)),
        config.aggregation,
        seed=seed,
        at_checkpoint=evaluate,
        after_round=None if resume is None else lambda rounds: resume.save(agent, rounds),
        resume=start,
    )
    env.close()
    eval_env.close()
    return {
        "counts": result.counts.to_dict(),
        "training": result.episodes,
        "steps": result.steps,
        "at": result.checkpoints,
    }


def _baseline(config: Any, seed: int, goals: list[int], found: list[Probe] | None = None) -> dict[str, Any]:
    """The PETS-style baseline's rounds and its checkpoint evaluations."""
    steps, h = config.aggregation.episode_steps, config.plan.action.horizon
    env, eval_env = training_env(), gymnasium.make(ENV_ID)
    learner = PetsLearner(
        env, config.baseline, config.plan, step_cost(config.plan), seed=derived_seed(seed, 80)
    )

    def evaluate(point: int, counts: Counts) -> dict[str, Any]:
        if config.lockstep:  # one planner per goal, their searches made together
            envs = [gymnasium.make(ENV_ID) for _ in goals]
            episodes = [pets_record(e, h) for e in learner.run_together(envs, goals, steps)]
            for e in envs:
                e.close()
        else:
            episodes = [pets_record(learner.run(eval_env, s, steps, False, record=False), h) for s in goals]
        _log_point("baseline", seed, point, counts, episodes)
        ranking = score(found, pets_predictor(learner), config.plan) if found and learner.fitted else None
        return {"counts": counts.to_dict(), "episodes": episodes, "ranking": ranking}

    result = run_rounds(learner, config.aggregation, seed=seed, at_checkpoint=evaluate)
    training = [pets_record(e, h) for e in result.episodes]
    env.close()
    eval_env.close()
    return {
        "counts": result.counts.to_dict(),
        "training": training,
        "steps": result.steps,
        "at": result.checkpoints,
    }


def _probes(config: Any, seed: int) -> list[Probe]:
    """The seed's ranking probes: states of the ceiling's episodes (deterministic in the seed)."""
    env = gymnasium.make(ENV_ID)
    seeds = [derived_seed(seed, 93, g) for g in range(config.ranking.goals)]
    found = probes(env, config.plan, config.ranking, seeds)
    env.close()
    return found


def _reference(config: Any, seed: int, goals: list[int]) -> dict[str, Any]:
    """The goals run once by the planner's ceiling (the true simulator) and by random torques."""
    env, steps = gymnasium.make(ENV_ID), config.aggregation.episode_steps
    out = {
        "simulator": [simulator_episode(env, config.plan, s, steps) for s in goals],
        "random": [random_episode(env, s, steps) for s in goals],
    }
    env.close()
    return out


def run_part(config: Any, seed: int, part: str, resume: Any = None) -> dict[str, Any]:
    """One part of a seed (:data:`pusher_store.PARTS`): ``pal``, ``baseline`` or ``reference``.

    ``resume`` (``pal`` only; :class:`pusher_store.Resume`): ``restore(agent)`` returns the rounds'
    result of a stopped run with the agent restored (or None), and ``save(agent, result)`` is
    called after every round.

    Returns:
        ``pal`` / ``baseline``: the learner's run
        ``{"counts", "training": [Episode per round], "steps": [env steps after each round],
        "at": {checkpoint: {"counts", "episodes": [Episode per goal], "ranking": scores or None}}}``
        (``ranking``: :func:`pusher_ranking.score` on the seed's probes, None without probes or
        before a first fit); ``reference``: ``{"simulator": [Episode per goal], "random": [...]}``.
    """
    goals = evaluation_seeds(seed, config.eval_goals)
    if part == "reference":
        return _reference(config, seed, goals)
    if part == "pal":
        return _pal(config, seed, goals, _probes(config, seed), resume)
    if part != "baseline":
        raise ValueError(f"part must be 'pal', 'baseline' or 'reference', got {part!r}")
    if resume is not None:
        raise ValueError("only the 'pal' part resumes; the baseline's learner has no snapshot")
    return _baseline(config, seed, goals, _probes(config, seed))


def one_seed(config: Any, seed: int) -> dict[str, Any]:
    """Both learners' rounds, the ceiling and random torques for one seed.

    Args:
        config: the experiment's :class:`pal.experiments.closed_loop.pusher.Config`.
        seed: this run's seed (episode seeds, weights, samples).

    Returns:
        ``{"pal": run, "baseline": run, "simulator": [Episode per goal], "random": [Episode per goal]}``
        (the runs of :func:`run_part`).
    """
    out = {"pal": run_part(config, seed, "pal"), "baseline": run_part(config, seed, "baseline")}
    return out | run_part(config, seed, "reference")
