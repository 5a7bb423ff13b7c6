"""What the agent decides at a step: an action and why it was chosen (:class:`Decision`)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pal.agent.plan import Plan

__all__ = ["MODES", "Decision", "check_mode", "from_plan"]

#: Ways :meth:`Agent.decide` chooses an action.
MODES = ("babble", "curious", "goal")


@dataclass(frozen=True)
class Decision:
    """An action and why it was chosen.

    Attributes:
        mode: babble / curious / goal / hold.
        action: (A,) the action.
        targets: object -> (d,) target, m.
        predicted: object -> (d,) position the model predicts at the plan's horizon, m.
        objective: predicted distance to the targets at the horizon, m (None without a plan).
        step_mean, step_sd: object -> (d,) predicted displacement over this step and its sd, m.
        score: the curiosity score (gated disagreement; the contact method's information), or None.
        diagnostics: the contact method's gate, contact probability and CAI of the executed
            action per object (:func:`pal.agent.explore.diagnose`), else empty.
        sequence: (H, A) the planned sequence whose first action this is (None without a plan).
    """

    mode: str
    action: np.ndarray
    targets: dict[str, np.ndarray] = field(default_factory=dict)
    predicted: dict[str, np.ndarray] = field(default_factory=dict)
    objective: float | None = None
    step_mean: dict[str, np.ndarray] = field(default_factory=dict)
    step_sd: dict[str, np.ndarray] = field(default_factory=dict)
    score: float | None = None
    diagnostics: dict[str, dict[str, float]] = field(default_factory=dict)
    sequence: np.ndarray | None = None


def from_plan(p: Plan, mode: str | None = None, score: float | None = None) -> Decision:
    """The decision to execute a plan's first action (its mode unless ``mode`` is given)."""
    return Decision(
        mode or p.mode,
        p.action,
        p.targets,
        p.predicted,
        p.objective,
        p.step_mean,
        p.step_sd,
        score,
        sequence=p.sequence,
    )


def check_mode(mode: str) -> str:
    """``mode`` if it is one of :data:`MODES`, else a ValueError naming it."""
    if mode not in MODES:
        raise ValueError(f"mode {mode!r} unknown; expected one of {MODES}")
    return mode
