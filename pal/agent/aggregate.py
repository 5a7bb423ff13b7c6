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

An MPC episode gathers data only along the plans its model already prefers, so the model never
learns how the alternatives the planner compares would turn out. :class:`Exploration` perturbs
the executed actions of the model's episodes with colored noise,

    a_t = clip(pi_r(s_t) + sd (high - low) n_t)     n = colored noise over the episode (unit sd, 1/f^beta)

which puts transitions around the plans. The noise depends on the episode seed alone, so two
learners given the same ``seed`` execute the same perturbations. No state is ever restored.

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

from inference.planning import colored_noise
from pal.agent.loop import Agent
from pal.checks import check_float, check_int

__all__ = [
    "AgentLearner",
    "AggregationConfig",
    "Counts",
    "Exploration",
    "Learner",
    "Rollout",
    "RoundsResult",
    "aggregate",
    "derived_seed",
    "episode_seed",
    "goal_episode",
    "parameter_digest",
    "run_rounds",
]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Exploration:
    """Colored noise on the executed actions of the model's episodes (module docstring).

    Attributes:
        sd: the noise sd as a fraction of each action's range ``high - low`` (0: none).
        beta: the colour exponent of the noise over the episode's steps (0: white; 2: smooth drifts).
    """

    sd: float = 0.0
    beta: float = 2.0

    def __post_init__(self) -> None:
        check_float("exploration.sd", self.sd, 0.0)
        check_float("exploration.beta", self.beta, 0.0)

    def offsets(self, seed: int, steps: int, low: np.ndarray, high: np.ndarray) -> np.ndarray | None:
        """The action offsets ``(steps, A)`` of an episode seeded ``seed``; None when ``sd`` is 0.

        ``low``, ``high``: (A,) action bounds. The same seed gives the same unit noise for any bounds.
        """
        if self.sd == 0:
            return None
        lo, hi = np.asarray(low, dtype=np.float64), np.asarray(high, dtype=np.float64)
        if lo.ndim != 1 or lo.shape != hi.shape:
            raise ValueError(f"action bounds must be two (A,) arrays, got shapes {lo.shape} and {hi.shape}")
        generator = torch.Generator().manual_seed(derived_seed(seed, 11))
        unit = colored_noise((len(lo), steps), self.beta, generator, torch.float64).numpy().T
        return self.sd * (hi - lo) * unit


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
    """

    rounds: int = 60
    episode_steps: int = 100
    random_rounds: int = 1
    checkpoints: tuple[int, ...] = ()
    exploration: Exploration = Exploration()

    def __post_init__(self) -> None:
        if isinstance(self.rounds, int) and not isinstance(self.rounds, bool) and self.rounds < 1:
            raise ValueError(f"rounds is {self.rounds}; aggregation needs at least 1 round (episode + refit)")
        check_int("rounds", self.rounds)
        check_int("episode_steps", self.episode_steps)
        check_int("random_rounds", self.random_rounds, minimum=0, maximum=self.rounds)
        if not isinstance(self.exploration, Exploration):
            raise ValueError(f"exploration must be an Exploration, got {type(self.exploration).__name__}")
        points = tuple(check_int("checkpoints", c) for c in self.checkpoints)
        for a, b in itertools.pairwise(points):
            if b <= a:
                raise ValueError(f"checkpoints {list(points)} are not strictly increasing ({a} then {b})")
        if points and points[-1] > self.budget:
            raise ValueError(
                f"checkpoint {points[-1]} is beyond the step budget {self.budget} "
                f"(rounds {self.rounds} x episode_steps {self.episode_steps}); raise rounds or drop it"
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
        """The most environment steps the rounds take: ``rounds * episode_steps``."""
        return self.rounds * self.episode_steps


@dataclass
class Counts:
    """What aggregation spent: environment steps, episodes (random among them) and refits (warm among them)."""

    env_steps: int = 0
    episodes: int = 0
    random_episodes: int = 0
    refits: int = 0
    warm_refits: int = 0

    def to_dict(self) -> dict[str, int]:
        """The counts as a JSON-compatible dict."""
        return asdict(self)


@dataclass(frozen=True)
class Rollout:
    """One episode of a learner: the environment steps it took and the caller's record of it."""

    steps: int
    record: Any = None


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


@dataclass
class RoundsResult:
    """The rounds' counts, each episode's record, and ``at_checkpoint``'s result per checkpoint."""

    counts: Counts
    episodes: list[Any] = field(default_factory=list)
    steps: list[int] = field(default_factory=list)
    checkpoints: dict[int, Any] = field(default_factory=dict)


def derived_seed(*keys: int) -> int:
    """A 32-bit seed derived from ``keys`` (``numpy.random.SeedSequence``): independent streams per key tuple."""
    return int(np.random.SeedSequence(list(keys)).generate_state(1)[0])


def episode_seed(seed: int, r: int) -> int:
    """The reset seed :func:`run_rounds` gives round ``r``'s episode in a run seeded ``seed``."""
    return derived_seed(seed, 7, r)


def run_rounds(
    learner: Learner,
    config: AggregationConfig,
    *,
    seed: int = 0,
    at_checkpoint: Callable[[int, Counts], Any] | None = None,
    progress_bar: bool = False,
) -> RoundsResult:
    """Run ``config.rounds`` aggregation rounds (module docstring).

    Episode ``r`` resets with a seed derived from ``(seed, r)``, so two learners given the same
    ``seed`` see the same sequence of starts and goals.

    Returns:
        the counts, the episodes' records, the step count after each episode, and the
        ``at_checkpoint(checkpoint, counts)`` results keyed by checkpoint.
    """
    check_int("seed", seed, minimum=0)
    result = RoundsResult(Counts())
    counts, pending = result.counts, list(config.checkpoints)
    for r in tqdm(range(config.rounds), desc="aggregation", disable=not progress_bar, leave=False):
        random = r < config.random_rounds
        rollout = learner.episode(episode_seed(seed, r), config.episode_steps, random, config.exploration)
        counts.env_steps += rollout.steps
        counts.episodes += 1
        counts.random_episodes += int(random)
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
    return result


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
        self._digest: tuple[float, ...] | None = None

    def episode(self, seed: int, steps: int, random: bool, exploration: Exploration | None = None) -> Rollout:
        """One episode of the agent (:class:`Learner`)."""
        return self._episode(self.agent, seed, steps, random, exploration)

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
