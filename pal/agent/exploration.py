"""Exploration of a learner's own episodes: colored noise on its actions, and branches from saved states.

An MPC episode gathers data only along the plans its model already prefers, so the model never
learns how the alternatives its planner compares would turn out. Two remedies, both seeded by
the episode's seed alone (two learners given the same seed execute the same perturbations):

- :class:`Exploration` perturbs the executed actions of the model's episodes with colored noise,

      a_t = clip(pi(s_t) + sd (high - low) n_t)     n = colored noise over the episode (unit sd, 1/f^beta)

- :class:`Branching` adds perturbed continuations of an episode: from every ``every``-th state
  s_t (while ``t + steps`` fits in the episode), ``per_state`` short episodes restart from that
  exact simulator state and execute the episode's next ``steps`` actions plus colored noise,

      a'_{t+i} = clip(a_{t+i} + sd (high - low) n^{(t,k)}_i),    i = 0 .. steps - 1,  k = 0 .. per_state - 1

  so each push is seen with its neighbours. Restoring a state is a simulator privilege that a
  real body lacks (:class:`pal.sim.restore.StartFromState`); every branch step counts as an
  environment step.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from inference.planning import colored_noise
from pal.checks import check_float, check_int

__all__ = ["Branching", "Exploration", "branch_seed", "derived_seed"]


def derived_seed(*keys: int) -> int:
    """A 32-bit seed derived from ``keys`` (``numpy.random.SeedSequence``): independent streams per key tuple."""
    return int(np.random.SeedSequence(list(keys)).generate_state(1)[0])


def branch_seed(seed: int, t: int, k: int) -> int:
    """The noise seed of branch ``k`` from step ``t`` of the episode seeded ``seed``."""
    return derived_seed(seed, t, k)


@dataclass(frozen=True)
class Exploration:
    """Colored noise on executed actions (module docstring).

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
class Branching:
    """Perturbed continuations of an episode from its saved simulator states (module docstring).

    Attributes:
        every: a start every this many steps of the episode (from step 0).
        per_state: continuations per start (0: no branching).
        steps: the length of each continuation.
        noise: the colored noise on the episode's actions (sd as a fraction of the range).
    """

    every: int = 10
    per_state: int = 0
    steps: int = 25
    noise: Exploration = Exploration(sd=0.125, beta=2.0)

    def __post_init__(self) -> None:
        check_int("branching.every", self.every)
        check_int("branching.per_state", self.per_state, minimum=0)
        check_int("branching.steps", self.steps)
        if not isinstance(self.noise, Exploration):
            raise ValueError(f"branching.noise must be an Exploration, got {type(self.noise).__name__}")

    def starts(self, length: int) -> range:
        """The start steps of an episode of ``length`` steps (none when branching is off or it is too short)."""
        if self.per_state == 0:
            return range(0)
        return range(0, length - self.steps + 1, self.every)

    def steps_per_episode(self, length: int) -> int:
        """The environment steps the branches of one episode of ``length`` steps take."""
        return len(self.starts(length)) * self.per_state * self.steps

    def actions(
        self, seed: int, t: int, k: int, taken: np.ndarray, low: np.ndarray, high: np.ndarray
    ) -> np.ndarray:
        """Branch ``k``'s actions from step ``t``: ``clip(taken[t : t + steps] + noise)``, ``(steps, A)``.

        ``taken``: (T, A) the episode's executed actions; ``low``, ``high``: (A,) bounds.
        """
        base = np.asarray(taken, dtype=np.float64)
        if base.ndim != 2 or t < 0 or t + self.steps > len(base):
            raise ValueError(
                f"branch from step {t} needs {self.steps} actions of a (T, A) array, got shape {base.shape}"
            )
        base = base[t : t + self.steps]
        offsets = self.noise.offsets(branch_seed(seed, t, k), self.steps, low, high)
        return np.clip(base if offsets is None else base + offsets, low, high)
