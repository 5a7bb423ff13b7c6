"""Replanning every k steps: model-predictive control that executes k actions of each plan.

With ``PlanConfig.replan_every = k`` a planner (the agent's, the PETS-style baseline's and the
simulator's) plans at steps 0, k, 2k, ... of an episode and executes the plan's next actions
open loop in between; k = 1 is PETS's MPC, a new plan at every step. The next plan's warm
start is the last plan shifted by the actions executed from it
(:func:`inference.planning.shift_plan` with ``steps`` = that count). A plan is never held past
its horizon H (after H actions the planner plans again), so k > H acts as k = H. Planning costs
1 / k of what it costs at every step; the held actions react to nothing that happens meanwhile.
"""

from __future__ import annotations

from pal.checks import check_int

__all__ = ["Replanning"]


class Replanning:
    """When a planner plans, and which action of its current plan it executes (module docstring).

    Args:
        every: k >= 1 (``PlanConfig.replan_every``).
    """

    def __init__(self, every: int) -> None:
        self.every = check_int("replan_every", every)
        self.used = 0  # actions of the current plan executed; 0: no plan this episode

    def reset(self) -> None:
        """Forget the plan (a new episode, or the planner dropped it): the next step plans."""
        self.used = 0

    def due(self, horizon: int) -> bool:
        """True when the next step plans: no plan, or k (or all H) of its actions executed."""
        return self.used == 0 or self.used >= min(self.every, horizon)

    def take(self) -> int:
        """The index of the current plan's action to execute now (call when not :meth:`due`)."""
        if self.used == 0:
            raise ValueError("no plan to take an action from: plan first")
        index, self.used = self.used, self.used + 1
        return index

    def planned(self) -> None:
        """A new plan was made; its first action is executed now."""
        self.used = 1

    def shift(self) -> int:
        """The warm start's shift: the actions executed from the last plan (at least 1)."""
        return max(self.used, 1)
