"""Experiment ``pusher-data``: which training data teach the agent's Pusher-v5 model to rank pushes.

An MPC learner acts well when its model orders the candidate plans its planner compares as the
true dynamics would (:mod:`pal.experiments.closed_loop.pusher_ranking`). This experiment fits the
agent's world model (the ``pusher`` experiment's, ``model``) on two data sets and scores both on
the same ranking probes:

1. ``expert``: ``expert_episodes`` episodes of the planner's ceiling
   (:class:`pal.baselines.simulator_mpc.SimulatorMPC`, the learners' planner and cost with the
   true simulator), which reach the object and push it;
2. ``expert + continuations``: the same episodes plus perturbed continuations. From every
   ``continuations.every``-th state s_t of each expert episode (while ``t + steps`` fits in the
   episode), ``continuations.per_state`` short episodes restart from that exact simulator state
   and execute the expert's next ``steps`` torques plus colored noise
   (:class:`pal.agent.exploration.Branching`, the aggregation's branches applied to the expert):

       a_{t+i} = clip(a*_{t+i} + sd (high - low) n_i),    i = 0 .. steps - 1

   Each push is then seen with its neighbours. Restoring a state is a simulator privilege that a
   real body lacks; this experiment is a diagnosis of the model class and its data, not a protocol.

The agent reads every episode itself (the restored state is its reset), so both data sets are
the agent's own history. Scores per data set: median Spearman ``rho`` of the summed step cost,
``rho_obj`` of the final object-goal distance, and the ``regret`` of the model's pick, over the
probes of ``ranking.goals`` ceiling episodes (other seeds than the expert's).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import gymnasium
import numpy as np

from pal.agent import Agent, AgentConfig, ModelConfig, PlanConfig, pusher_spec
from pal.agent.aggregate import AgentLearner, Branching, Rollout, branch, derived_seed
from pal.agent.learn import site_data
from pal.baselines.simulator_mpc import PUSHER_BODIES, SimulatorMPC, pusher_observation
from pal.checks import check_int
from pal.experiments.closed_loop.pusher import PLAN, PUSH_MODEL
from pal.experiments.closed_loop.pusher import TINY as PUSHER_TINY
from pal.experiments.closed_loop.pusher_ranking import (
    RankingConfig,
    arm_forced_score,
    pal_predictor,
    probes,
    score,
)
from pal.experiments.closed_loop.pusher_runs import (
    ENV_ID,
    MOVED,
    Episode,
    agent_episode,
    evaluation_seeds,
    step_cost,
)
from pal.lab.registry import register
from pal.lab.report import Precondition, Report, Table, Target
from pal.sim.restore import StartFromState

__all__ = ["Config", "run"]


@dataclass(frozen=True)
class Config:
    """The ``pusher-data`` protocol (module docstring).

    Attributes:
        seed: expert episodes reset with seeds from (seed, 70, e); the agents' seed.
        expert_episodes: ceiling episodes of ``episode_steps`` steps (Pusher-v5 truncates at 100).
        continuations: the perturbed continuations of the second data set.
        model: the agent's world model (default: the ``pusher`` experiment's with the MJCF body, and
            the object's sites in the push frame with the claw's points, :mod:`pal.agent.graph_frame`).
        plan: the planner and step cost of the ceiling and the probes.
        ranking: the probes (their ceiling episodes reset with seeds from (seed, 93, g)).
        eval_goals: closed-loop episodes of the agent's MPC with each fitted model, reset with the
            ``pusher`` experiment's evaluation seeds (seed, 91, g) (0: none): does a better
            ranking bring the object closer to its goal?
    """

    seed: int = 0
    expert_episodes: int = 10
    episode_steps: int = 100
    continuations: Branching = Branching(every=10, per_state=10, steps=25)
    model: ModelConfig = PUSH_MODEL
    plan: PlanConfig = PLAN
    ranking: RankingConfig = RankingConfig()
    eval_goals: int = 4

    def __post_init__(self) -> None:
        check_int("seed", self.seed, minimum=0)
        check_int("expert_episodes", self.expert_episodes)
        check_int("eval_goals", self.eval_goals, minimum=0)
        check_int("episode_steps", self.episode_steps, maximum=100)
        if not isinstance(self.continuations, Branching):
            raise ValueError(f"continuations must be a Branching, got {type(self.continuations).__name__}")
        check_int("continuations.per_state", self.continuations.per_state)
        if self.continuations.steps > self.episode_steps:
            raise ValueError(
                f"continuations.steps {self.continuations.steps} exceeds episode_steps {self.episode_steps}"
            )


QUICK = Config(expert_episodes=3, continuations=Branching(every=20, per_state=4, steps=25), eval_goals=1)
TINY = Config(
    expert_episodes=1,
    episode_steps=6,
    continuations=Branching(every=3, per_state=2, steps=3),
    model=PUSHER_TINY.model,
    plan=PUSHER_TINY.plan,
    ranking=PUSHER_TINY.ranking,
    eval_goals=1,
)


def _agent_config(config: Config) -> AgentConfig:
    return AgentConfig(model=config.model, plan=config.plan, reset_every=None, servo=False)


def _agent(config: Config) -> Agent:
    cfg = _agent_config(config)
    env = StartFromState(gymnasium.make(ENV_ID), pusher_observation, PUSHER_BODIES)
    return Agent(env, pusher_spec(), cfg, seed=config.seed)


def _expert(agent: Agent, config: Config) -> list[tuple[int, np.ndarray, np.ndarray]]:
    """The ceiling's episodes through ``agent``: ``(reset seed, states (T, S), torques (T, A))`` each."""
    out = []
    for e in range(config.expert_episodes):
        seed = derived_seed(config.seed, 70, e)
        agent.reset(seed=seed)
        planner = SimulatorMPC(
            agent.env, config.plan, step_cost(config.plan), pusher_observation, PUSHER_BODIES, seed=seed
        )
        states, torques = [], []
        for _ in range(config.episode_steps):
            states.append(planner.state())
            action = np.clip(planner.act()[0], agent.low, agent.high)
            torques.append(action)
            agent.step(action)
            if agent.done:
                break
        out.append((seed, np.asarray(states), np.asarray(torques)))
    return out


def _replay(agent: Agent, episodes: list[tuple[int, np.ndarray, np.ndarray]]) -> None:
    for seed, _, torques in episodes:
        agent.reset(seed=seed)
        for a in torques:
            agent.step(a)


def _continue(agent: Agent, episodes: list[tuple[int, np.ndarray, np.ndarray]], c: Branching) -> None:
    """The perturbed continuations of the expert's episodes (module docstring) into ``agent``'s history."""
    learner = AgentLearner(agent)
    for seed, states, torques in episodes:
        branch(learner, seed, Rollout(len(torques), None, states, torques), c)


def _closed_loop(agent: Agent, config: Config) -> list[Episode]:
    """The agent's MPC with its current model on the evaluation goals, on its own environment (no data added)."""
    env = gymnasium.make(ENV_ID)
    judge = Agent(
        env, pusher_spec(), _agent_config(config), seed=derived_seed(config.seed, 92), model=agent.model
    )
    goals = evaluation_seeds(config.seed, config.eval_goals)
    episodes = [agent_episode(judge, s, config.episode_steps, config.plan.action.horizon) for s in goals]
    env.close()
    return episodes


def _scored(agent: Agent, found: list, config: Config, label: str) -> list[Any]:
    """One table row: the agent's fit on its history, its ranking scores on the probes, its closed loop."""
    clock = time.process_time()
    agent.refit()
    fit = time.process_time() - clock
    moving = int(site_data(agent.history, agent.spec, config=agent.config.model)["contact.object"].sum())
    s = score(found, pal_predictor(agent.model, config.plan), config.plan)
    forced = arm_forced_score(found, agent.model, config.plan)
    episodes = _closed_loop(agent, config)
    row = [
        label,
        len(agent.history),
        moving,
        fit,
        s["rho"],
        s["rho_obj"],
        s["regret"],
        s["probes"],
        forced["rho_obj"],
        _cm(forced["error"]),
        _cm(forced["spread"]),
    ]
    if not episodes:
        return [*row, None, None, None]
    start = float(np.median([e.start_planar for e in episodes]))
    final = float(np.median([e.final_planar for e in episodes]))
    return [*row, start, final, float(np.mean([e.moved > MOVED for e in episodes]))]


def _cm(metres: float | int | None) -> float | None:
    return None if metres is None else 100.0 * float(metres)


@register("pusher-data", config=Config, quick=QUICK, tiny=TINY)
def run(config: Config, progress_bar: bool = False) -> Report:
    """How the agent's Pusher-v5 model ranks candidate pushes after two kinds of training data (module docstring)."""
    env = gymnasium.make(ENV_ID)
    found = probes(
        env,
        config.plan,
        config.ranking,
        [derived_seed(config.seed, 93, g) for g in range(config.ranking.goals)],
    )
    env.close()
    expert_agent = _agent(config)
    episodes = _expert(expert_agent, config)
    rows = [_scored(expert_agent, found, config, "expert")]
    both = _agent(config)
    _replay(both, episodes)
    _continue(both, episodes, config.continuations)
    rows.append(_scored(both, found, config, "expert + continuations"))
    expert_agent.env.close()
    both.env.close()
    header = [
        "data",
        "transitions",
        "moving",
        "fit CPU [s]",
        "rho",
        "rho_obj",
        "regret",
        "probes",
        "rho_obj, arm from the truth",
        "final object error, arm from the truth [cm]",
        "candidates' final spread [cm]",
        "closed-loop start x-y, median [m]",
        "closed-loop final x-y, median [m]",
        "closed-loop moved share",
    ]
    metrics = {r[0]: dict(zip(header[1:], r[1:], strict=True)) for r in rows}
    before, after = (m["rho_obj"] for m in metrics.values())
    probe_count = metrics["expert"]["probes"]
    gain = None if before is None or after is None else after - before
    target = Target(
        "continuations_rho_obj_gain",
        gain,
        0.3,
        ">=",
        "rho_obj with the continuations minus without: do pushes seen with their neighbours teach the ranking?",
        Precondition(
            config.expert_episodes >= 10 and probe_count >= 15 and gain is not None,
            f">= 10 expert episodes and >= 15 probes, rho_obj defined for both "
            f"(this run: {config.expert_episodes} episodes, {probe_count} probes)",
        ),
    )
    return Report(
        title="Pusher-v5: which training data teach the agent's model to rank candidate pushes",
        metrics=metrics,
        tables=[
            Table(
                "Ranking of the probes' candidate plans by training data",
                header,
                rows,
                caption="Medians over the probes: Spearman correlation of the model's summed step cost (rho) "
                "and final object-goal distance (rho_obj) with the true ones, and the regret of its pick "
                "(0: the best candidate, 1: a median one). Moving: transitions whose contact switch is on "
                "(the object moved more than 3 position_sigma). Arm from the truth: rho_obj with the arm's sites "
                "set to each candidate's true trajectory, the object layer's own ranking; its final object x-y error (RMS over "
                "the candidates) beside the spread of the true final positions: an error above the spread ranks worse "
                "than one guess for all. Closed loop: the agent's MPC with the fitted "
                f"model on {config.eval_goals} evaluation goals (the pusher experiment's), object-goal distance "
                f"at the start and the end, and the share of episodes that moved the object > {MOVED * 1000:g} mm.",
            )
        ],
        targets=[target],
        notes=[
            f"{config.expert_episodes} ceiling episodes of {config.episode_steps} steps; continuations: "
            f"{config.continuations.per_state} per start, every {config.continuations.every} steps, "
            f"{config.continuations.steps} steps each, noise sd {config.continuations.noise.sd} of the range, "
            f"beta {config.continuations.noise.beta}. Restoring states is a simulator privilege: a diagnosis, "
            "not a protocol."
        ],
    )
