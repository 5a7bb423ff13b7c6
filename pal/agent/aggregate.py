"""Data aggregation (PETS-style): act for an episode, append its transitions, refit warm-started, repeat.

With D the learner's data and f_r its model after round r:

    D_0 = {}                        f_0 = the initial (unfitted) model
    tau_r = episode(pi_r)           pi_r = random   for r < random_rounds
                                    pi_r = MPC(f_{r-1}) otherwise
    D_r = D_{r-1} + tau_r           f_r = fit(f_{r-1}, D_r)   (warm start: the fit starts from f_{r-1})

as in Chua et al. (2018) and mbrl-lib's PETS, where the first round is one random episode and
every later episode is gathered with the model. The babbling-heavy protocol (many random
steps, then few model-driven episodes) is the same loop with ``random_rounds`` > 1; no refit runs
between two random rounds, since a random round does not use the model.

An MPC episode gathers data only along the plans its model already prefers. Two remedies of
:mod:`pal.agent.exploration` apply to the model's episodes: colored noise on the executed
actions (:class:`Exploration`, no state restored), and perturbed continuations from the
episode's saved simulator states (:class:`Branching`, a simulator privilege: the learner's
environment must be wrapped in :class:`pal.sim.restore.StartFromState`). Branch steps count as
environment steps, and the refit after the episode sees them.

:func:`run_rounds` runs the loop for any :class:`Learner` (the agent here, the PETS-style
baseline in :mod:`pal.baselines.pets_aggregate`) and calls ``at_checkpoint`` after the first
refit whose environment-step count reaches each checkpoint (the learning curve is scored there);
:func:`aggregate` runs it for an :class:`pal.agent.Agent` in goal mode.
:class:`Counts` holds the environment steps, episodes and refits, and how many refits started
from the previous fit's weights.
"""

from __future__ import annotations

import itertools
import logging
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from typing import Any, Protocol

import numpy as np
import torch
from tqdm import tqdm

from pal.agent.exploration import Branching, Exploration, derived_seed
from pal.agent.loop import Agent
from pal.checks import check_int
from pal.sim.restore import StartFromState, find_wrapper

__all__ = [
    "AgentLearner",
    "AggregationConfig",
    "Branching",
    "BranchingLearner",
    "Counts",
    "Exploration",
    "Learner",
    "Rollout",
    "RoundsResult",
    "aggregate",
    "branch",
    "derived_seed",
    "episode_seed",
    "goal_episode",
    "parameter_digest",
    "recorded",
    "run_rounds",
]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class AggregationConfig:
    """The aggregation protocol (module docstring).

    Attributes:
        rounds: episodes R, each followed by a refit (after the last random round, for random ones).
        episode_steps: environment steps per episode (an episode the environment ends early is shorter).
        random_rounds: leading episodes of random actions (1: PETS; more: the babbling-heavy protocol).
        checkpoints: environment-step counts, strictly increasing, from the first fit
            (``max(random_rounds, 1) * episode_steps``) to the budget ``rounds * episode_steps``,
            at which ``at_checkpoint`` is called.
        exploration: the noise on the executed actions of the model's episodes (default none).
        branching: the perturbed continuations of the model's episodes (default none).
    """

    rounds: int = 60
    episode_steps: int = 100
    random_rounds: int = 1
    checkpoints: tuple[int, ...] = ()
    exploration: Exploration = Exploration()
    branching: Branching = Branching()

    def __post_init__(self) -> None:
        if isinstance(self.rounds, int) and not isinstance(self.rounds, bool) and self.rounds < 1:
            raise ValueError(f"rounds is {self.rounds}; aggregation needs at least 1 round (episode + refit)")
        check_int("rounds", self.rounds)
        check_int("episode_steps", self.episode_steps)
        check_int("random_rounds", self.random_rounds, minimum=0, maximum=self.rounds)
        if not isinstance(self.exploration, Exploration):
            raise ValueError(f"exploration must be an Exploration, got {type(self.exploration).__name__}")
        if not isinstance(self.branching, Branching):
            raise ValueError(f"branching must be a Branching, got {type(self.branching).__name__}")
        points = tuple(check_int("checkpoints", c) for c in self.checkpoints)
        for a, b in itertools.pairwise(points):
            if b <= a:
                raise ValueError(f"checkpoints {list(points)} are not strictly increasing ({a} then {b})")
        if points and points[-1] > self.budget:
            raise ValueError(
                f"checkpoint {points[-1]} is beyond the step budget {self.budget} "
                f"(rounds {self.rounds} x episode_steps {self.episode_steps}, with branches); raise rounds or drop it"
            )
        first = max(self.random_rounds, 1) * self.episode_steps
        if points and points[0] < first:
            raise ValueError(
                f"checkpoint {points[0]} comes before the first fit at {first} steps (after {self.random_rounds} "
                f"random rounds of {self.episode_steps} steps), so it would score the model fitted there; "
                f"start the checkpoints at {first} or lower random_rounds"
            )
        object.__setattr__(self, "checkpoints", points)

    @property
    def budget(self) -> int:
        """The most environment steps the rounds take: ``rounds * episode_steps`` plus the model episodes' branches."""
        model_rounds = self.rounds - self.random_rounds
        return self.rounds * self.episode_steps + model_rounds * self.branching.steps_per_episode(
            self.episode_steps
        )


@dataclass
class Counts:
    """What aggregation spent: environment steps, episodes (random among them, and branches) and refits (warm among them).

    ``env_steps`` counts the branches' steps too; ``branch_steps`` counts them alone.
    """

    env_steps: int = 0
    episodes: int = 0
    random_episodes: int = 0
    branches: int = 0
    branch_steps: int = 0
    refits: int = 0
    warm_refits: int = 0

    def to_dict(self) -> dict[str, int]:
        """The counts as a JSON-compatible dict."""
        return asdict(self)


@dataclass(frozen=True)
class Rollout:
    """One episode of a learner: the environment steps it took, the caller's record of it and its trace.

    ``states`` (T, S) and ``actions`` (T, A): the simulator states before each step and the
    executed actions, for branching (None when the learner's environment does not record them).
    """

    steps: int
    record: Any = None
    states: np.ndarray | None = None
    actions: np.ndarray | None = None


class Learner(Protocol):
    """What :func:`run_rounds` drives: episodes that add to the learner's data, and warm refits."""

    def episode(self, seed: int, steps: int, random: bool, exploration: Exploration | None = None) -> Rollout:
        """Act for up to ``steps`` steps from ``reset(seed=seed)``, appending the transitions to the data.

        ``exploration`` (model episodes only): add ``exploration.offsets(seed, steps, low, high)`` to the actions.
        """
        ...

    def refit(self) -> bool:
        """Refit on all data from the current weights; True when it started from the previous fit's weights."""
        ...


class BranchingLearner(Learner, Protocol):
    """A :class:`Learner` that can restart from a saved simulator state (for :class:`Branching`)."""

    low: np.ndarray
    high: np.ndarray

    def branch(self, seed: int, state: np.ndarray, actions: np.ndarray) -> int:
        """Execute ``actions`` (K, A) from ``reset(seed=seed)`` restored to ``state``, appending the transitions.

        Returns the environment steps taken (fewer than K when the environment ends the episode).
        """
        ...


@dataclass
class RoundsResult:
    """The rounds' counts, each episode's record, and ``at_checkpoint``'s result per checkpoint."""

    counts: Counts
    episodes: list[Any] = field(default_factory=list)
    steps: list[int] = field(default_factory=list)
    checkpoints: dict[int, Any] = field(default_factory=dict)


def episode_seed(seed: int, r: int) -> int:
    """The reset seed :func:`run_rounds` gives round ``r``'s episode in a run seeded ``seed``."""
    return derived_seed(seed, 7, r)


def run_rounds(
    learner: Learner,
    config: AggregationConfig,
    *,
    seed: int = 0,
    at_checkpoint: Callable[[int, Counts], Any] | None = None,
    after_round: Callable[[RoundsResult], Any] | None = None,
    resume: RoundsResult | None = None,
    progress_bar: bool = False,
) -> RoundsResult:
    """Run ``config.rounds`` aggregation rounds (module docstring).

    Episode ``r`` resets with a seed derived from ``(seed, r)``, so two learners given the same
    ``seed`` see the same sequence of starts and goals.

    Args:
        learner: the learner (:class:`Learner`).
        config: rounds, episode length, random rounds, checkpoints, exploration, branching.
        seed: the run's seed.
        at_checkpoint: ``(checkpoint, counts) -> result``, called at each checkpoint (after the
            refit of the round that reaches it).
        after_round: called with the result so far at the end of every round that refits (after
            its checkpoints' results are in), e.g. to snapshot the learner
            (:mod:`pal.agent.snapshot`) so that a stopped run resumes.
        resume: the result handed to ``after_round`` by an earlier run with the same
            learner settings, config and seed, the learner restored to its state then: the rounds
            go on from round ``resume.counts.episodes``, as if never stopped.
        progress_bar: show a progress bar over the rounds.

    Returns:
        the counts, the episodes' records, the step count after each episode, and the
        ``at_checkpoint(checkpoint, counts)`` results keyed by checkpoint.

    Raises:
        ValueError: a ``resume`` whose records do not match its counts or lie beyond ``config``.
    """
    check_int("seed", seed, minimum=0)
    branching = config.branching
    if branching.per_state and not callable(getattr(learner, "branch", None)):
        raise ValueError(
            f"branching.per_state is {branching.per_state} but {type(learner).__name__} cannot branch "
            "(it needs a branch(seed, state, actions) method and an environment wrapped in StartFromState)"
        )
    result = RoundsResult(Counts()) if resume is None else _resumed(resume, config)
    counts = result.counts
    pending = [c for c in config.checkpoints if c > counts.env_steps and c not in result.checkpoints]
    first = counts.episodes
    for r in tqdm(
        range(first, config.rounds), desc="aggregation", initial=first, disable=not progress_bar, leave=False
    ):
        random = r < config.random_rounds
        rollout = learner.episode(episode_seed(seed, r), config.episode_steps, random, config.exploration)
        counts.env_steps += rollout.steps
        counts.episodes += 1
        counts.random_episodes += int(random)
        if not random and branching.per_state:
            made, steps = branch(learner, episode_seed(seed, r), rollout, branching)  # type: ignore[arg-type]
            counts.branches, counts.branch_steps = counts.branches + made, counts.branch_steps + steps
            counts.env_steps += steps
        result.episodes.append(rollout.record)
        result.steps.append(counts.env_steps)
        if random and r + 1 < config.random_rounds:
            continue  # the next round is random too: it does not use the model
        counts.warm_refits += int(learner.refit())
        counts.refits += 1
        log.info("aggregation round %d: %s", r, counts)
        while pending and counts.env_steps >= pending[0]:
            point = pending.pop(0)
            if at_checkpoint is not None:
                result.checkpoints[point] = at_checkpoint(point, replace(counts))
        if after_round is not None:
            after_round(result)
    return result


def _resumed(resume: RoundsResult, config: AggregationConfig) -> RoundsResult:
    """A copy of ``resume`` to go on from, checked against ``config``."""
    n = resume.counts.episodes
    if not (len(resume.episodes) == len(resume.steps) == n <= config.rounds):
        raise ValueError(
            f"resume holds {len(resume.episodes)} episodes and {len(resume.steps)} step counts for "
            f"{n} counted episodes; expected equal numbers, at most config.rounds = {config.rounds}"
        )
    if n < config.random_rounds:
        raise ValueError(
            f"resume after {n} episodes, within the {config.random_rounds} random rounds (no refit yet)"
        )
    return RoundsResult(
        replace(resume.counts), list(resume.episodes), list(resume.steps), dict(resume.checkpoints)
    )


def branch(learner: BranchingLearner, seed: int, rollout: Rollout, branching: Branching) -> tuple[int, int]:
    """Run ``branching``'s continuations of ``rollout`` (an episode reset with ``seed``) through ``learner``.

    Returns ``(branches, environment steps)``.

    Raises:
        ValueError: the rollout carries no states or actions (its environment did not record them).
    """
    if rollout.states is None or rollout.actions is None:
        raise ValueError(
            "branching needs the episode's simulator states and actions: wrap the learner's environment "
            "in pal.sim.restore.StartFromState"
        )
    made = steps = 0
    for t in branching.starts(len(rollout.actions)):
        for k in range(branching.per_state):
            actions = branching.actions(seed, t, k, rollout.actions, learner.low, learner.high)
            steps += learner.branch(seed, rollout.states[t], actions)
            made += 1
    return made, steps


def recorded(env: Any, rollout: Rollout) -> Rollout:
    """``rollout`` with the states and actions its episode left in ``env``'s :class:`StartFromState` (if any)."""
    recorder = find_wrapper(env, StartFromState)
    if recorder is None:
        return rollout
    return replace(rollout, states=recorder.states, actions=recorder.actions)


def parameter_digest(module: torch.nn.Module) -> tuple[float, ...]:
    """A fingerprint of a module's parameters (sum and sum of squares of each), to tell warm fits from fresh ones."""
    with torch.no_grad():
        return tuple(float(v) for p in module.parameters() for v in (p.sum(), p.pow(2).sum()))


def goal_episode(
    agent: Agent, seed: int, steps: int, random: bool, exploration: Exploration | None = None
) -> Rollout:
    """The agent in goal mode (MPC towards its goal) or random actions for up to ``steps`` steps from ``reset(seed)``.

    Every step goes into the agent's history; ``exploration`` perturbs the MPC actions
    (:meth:`Exploration.offsets`). The record is the list of decisions (None for random steps).
    """
    agent.reset(seed=seed)
    offsets = (
        None if random or exploration is None else exploration.offsets(seed, steps, agent.low, agent.high)
    )
    decisions: list[Any] = []
    for t in range(steps):
        if random:
            decisions.append(None)
            agent.step(agent.random_action())
        else:
            decision = agent.decide("goal")
            decisions.append(decision)
            agent.step(decision.action if offsets is None else decision.action + offsets[t])
        if agent.done:
            break
    return Rollout(len(decisions), decisions)


class AgentLearner:
    """An :class:`pal.agent.Agent` as a :class:`Learner`: its history is the data, :meth:`Agent.refit` the fit.

    Args:
        agent: the agent (its ``reset_every`` is not used: episodes are the rounds').
        episode: ``(agent, seed, steps, random, exploration) -> Rollout`` (default :func:`goal_episode`).
    """

    def __init__(self, agent: Agent, episode: Callable[..., Rollout] | None = None) -> None:
        self.agent = agent
        self._episode = episode or goal_episode
        # a fitted agent's next refit starts from its weights: warm (also after a restored snapshot)
        self._digest: tuple[float, ...] | None = parameter_digest(agent.model) if agent.fitted else None

    @property
    def low(self) -> np.ndarray:
        """(A,) the agent's lower action bounds."""
        return self.agent.low

    @property
    def high(self) -> np.ndarray:
        """(A,) the agent's upper action bounds."""
        return self.agent.high

    def episode(self, seed: int, steps: int, random: bool, exploration: Exploration | None = None) -> Rollout:
        """One episode of the agent (:class:`Learner`), with its trace when its environment records one."""
        return recorded(self.agent.env, self._episode(self.agent, seed, steps, random, exploration))

    def branch(self, seed: int, state: np.ndarray, actions: np.ndarray) -> int:
        """Execute ``actions`` from the restored ``state`` into the agent's history (:class:`BranchingLearner`)."""
        self.agent.reset(seed=seed, options={"state": state})
        taken = 0
        for a in actions:
            self.agent.step(a)
            taken += 1
            if self.agent.done:
                break
        return taken

    def refit(self) -> bool:
        """Refit the agent's model on its whole history, from its current weights (:class:`Learner`)."""
        warm = self._digest is not None and parameter_digest(self.agent.model) == self._digest
        self.agent.refit()
        self._digest = parameter_digest(self.agent.model)
        return warm


def aggregate(
    agent: Agent,
    config: AggregationConfig,
    *,
    seed: int | None = None,
    at_checkpoint: Callable[[int, Counts], Any] | None = None,
    progress_bar: bool = False,
) -> RoundsResult:
    """Aggregation rounds of ``agent`` in goal mode (module docstring); ``seed`` defaults to the agent's."""
    return run_rounds(
        AgentLearner(agent),
        config,
        seed=agent.seed if seed is None else seed,
        at_checkpoint=at_checkpoint,
        progress_bar=progress_bar,
    )
