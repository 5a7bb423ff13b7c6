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
   (:class:`pal.agent.aggregate.Exploration`):

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
from dataclasses import dataclass, replace
from typing import Any

import gymnasium
import mujoco
import numpy as np

from pal.agent import Agent, AgentConfig, ModelConfig, PlanConfig, pusher_spec
from pal.agent.aggregate import Exploration, derived_seed
from pal.agent.learn import site_data
from pal.baselines.simulator_mpc import SimulatorMPC, pusher_observation
from pal.checks import check_int
from pal.experiments.closed_loop.pusher import MODEL, PLAN
from pal.experiments.closed_loop.pusher import TINY as PUSHER_TINY
from pal.experiments.closed_loop.pusher_ranking import RankingConfig, pal_predictor, probes, score
from pal.experiments.closed_loop.pusher_runs import ENV_ID, step_cost
from pal.lab.registry import register
from pal.lab.report import Precondition, Report, Table, Target

__all__ = ["Config", "Continuations", "StartFromState", "run"]

_FULL = mujoco.mjtState.mjSTATE_FULLPHYSICS
_BODIES = ("tips_arm", "object", "goal")


@dataclass(frozen=True)
class Continuations:
    """The perturbed continuations (module docstring).

    Attributes:
        every: a start every this many steps of an expert episode (from step 0).
        per_state: continuations per start. steps: their length.
        noise: the colored noise on the expert's torques (sd as a fraction of the range).
    """

    every: int = 10
    per_state: int = 10
    steps: int = 25
    noise: Exploration = Exploration(sd=0.125, beta=2.0)

    def __post_init__(self) -> None:
        for name in ("every", "per_state", "steps"):
            check_int(f"continuations.{name}", getattr(self, name))
        if not isinstance(self.noise, Exploration):
            raise ValueError(f"continuations.noise must be an Exploration, got {type(self.noise).__name__}")


@dataclass(frozen=True)
class Config:
    """The ``pusher-data`` protocol (module docstring).

    Attributes:
        seed: expert episodes reset with seeds from (seed, 70, e); the agents' seed.
        expert_episodes: ceiling episodes of ``episode_steps`` steps (Pusher-v5 truncates at 100).
        continuations: the perturbed continuations of the second data set.
        model: the agent's world model (default: the ``pusher`` experiment's with the MJCF body).
        plan: the planner and step cost of the ceiling and the probes.
        ranking: the probes (their ceiling episodes reset with seeds from (seed, 93, g)).
    """

    seed: int = 0
    expert_episodes: int = 10
    episode_steps: int = 100
    continuations: Continuations = Continuations()
    model: ModelConfig = replace(MODEL, kinematics="mjcf", dynamics="mjcf")
    plan: PlanConfig = PLAN
    ranking: RankingConfig = RankingConfig()

    def __post_init__(self) -> None:
        check_int("seed", self.seed, minimum=0)
        check_int("expert_episodes", self.expert_episodes)
        check_int("episode_steps", self.episode_steps, maximum=100)
        if not isinstance(self.continuations, Continuations):
            raise ValueError(
                f"continuations must be a Continuations, got {type(self.continuations).__name__}"
            )
        if self.continuations.steps > self.episode_steps:
            raise ValueError(
                f"continuations.steps {self.continuations.steps} exceeds episode_steps {self.episode_steps}"
            )


QUICK = Config(expert_episodes=3, continuations=Continuations(every=20, per_state=4))
TINY = Config(
    expert_episodes=1,
    episode_steps=6,
    continuations=Continuations(every=3, per_state=2, steps=3),
    model=replace(PUSHER_TINY.model, kinematics="mjcf", dynamics="mjcf", position_sigma=1e-4),
    plan=PUSHER_TINY.plan,
    ranking=PUSHER_TINY.ranking,
)


class StartFromState(gymnasium.Wrapper):
    """Pusher-v5 whose ``reset(options={"state": s})`` continues from a saved MuJoCo state.

    ``s`` is a full-physics state vector (``mujoco.mj_getState`` with ``mjSTATE_FULLPHYSICS``);
    without it, ``reset`` is the environment's own. The observation is Pusher-v5's layout, read
    from the restored state (:func:`pal.baselines.simulator_mpc.pusher_observation`): its body
    positions are those of the state itself, while the environment's own observation after a
    step reads them as computed before the step's last substep (they differ by one substep of
    motion, millimetres). Every later step is the environment's.
    """

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict]:
        """Reset with ``seed``; then, given ``options["state"]``, restore that state."""
        obs, info = self.env.reset(seed=seed)
        state = (options or {}).get("state")
        if state is None:
            return obs, info
        sim = self.env.unwrapped
        size = mujoco.mj_stateSize(sim.model, _FULL)
        s = np.asarray(state, dtype=np.float64)
        if s.shape != (size,) or not np.all(np.isfinite(s)):
            raise ValueError(
                f"state has shape {s.shape}; expected a finite full-physics state of shape ({size},)"
            )
        mujoco.mj_setState(sim.model, sim.data, s, _FULL)
        mujoco.mj_forward(sim.model, sim.data)
        bodies = {b: sim.data.body(b).xpos.copy() for b in _BODIES}
        return pusher_observation(sim.data.qpos.copy(), sim.data.qvel.copy(), bodies), info


def _agent(config: Config) -> Agent:
    cfg = AgentConfig(model=config.model, plan=config.plan, reset_every=None, servo=False)
    return Agent(StartFromState(gymnasium.make(ENV_ID)), pusher_spec(), cfg, seed=config.seed)


def _expert(agent: Agent, config: Config) -> list[tuple[int, np.ndarray, np.ndarray]]:
    """The ceiling's episodes through ``agent``: ``(reset seed, states (T, S), torques (T, A))`` each."""
    out = []
    for e in range(config.expert_episodes):
        seed = derived_seed(config.seed, 70, e)
        agent.reset(seed=seed)
        planner = SimulatorMPC(
            agent.env, config.plan, step_cost(config.plan), pusher_observation, _BODIES, seed=seed
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


def _continue(agent: Agent, episodes: list[tuple[int, np.ndarray, np.ndarray]], c: Continuations) -> None:
    """The perturbed continuations of every ``c.every``-th state (module docstring) into ``agent``'s history."""
    for seed, states, torques in episodes:
        for t in range(0, len(torques) - c.steps + 1, c.every):
            for k in range(c.per_state):
                agent.reset(seed=seed, options={"state": states[t]})
                offsets = c.noise.offsets(derived_seed(seed, t, k), c.steps, agent.low, agent.high)
                base = torques[t : t + c.steps]
                for i in range(c.steps):
                    agent.step(base[i] if offsets is None else base[i] + offsets[i])


def _scored(agent: Agent, found: list, plan: PlanConfig, label: str) -> list[Any]:
    """One table row: the agent's fit on its history, and its ranking scores on the probes."""
    start = time.process_time()
    agent.refit()
    fit = time.process_time() - start
    moving = int(site_data(agent.history, agent.spec, config=agent.config.model)["contact.object"].sum())
    s = score(found, pal_predictor(agent.model, plan), plan)
    return [label, len(agent.history), moving, fit, s["rho"], s["rho_obj"], s["regret"], s["probes"]]


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
    rows = [_scored(expert_agent, found, config.plan, "expert")]
    both = _agent(config)
    _replay(both, episodes)
    _continue(both, episodes, config.continuations)
    rows.append(_scored(both, found, config.plan, "expert + continuations"))
    expert_agent.env.close()
    both.env.close()
    header = ["data", "transitions", "moving", "fit CPU [s]", "rho", "rho_obj", "regret", "probes"]
    metrics = {r[0]: dict(zip(header[1:], r[1:], strict=True)) for r in rows}
    before, after = (m["rho_obj"] for m in metrics.values())
    gain = None if before is None or after is None else after - before
    target = Target(
        "continuations_rho_obj_gain",
        gain,
        0.3,
        ">=",
        "rho_obj with the continuations minus without: do pushes seen with their neighbours teach the ranking?",
        Precondition(
            config.expert_episodes >= 10 and rows[0][-1] >= 15 and gain is not None,
            f">= 10 expert episodes and >= 15 probes, rho_obj defined for both "
            f"(this run: {config.expert_episodes} episodes, {rows[0][-1]} probes)",
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
                "(the object moved more than 3 position_sigma).",
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
