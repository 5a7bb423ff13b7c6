"""Act's bookkeeping: one executed step as a row of the sensorimotor history (:mod:`pal.agent.history`).

Missing evidence (a lost object, no effector) is NaN or empty in the row, inside the store only.
Ground truth is copied from what the environment reported in ``info`` (:attr:`pal.agent.senses.Percept.evaluation`);
for a state-based object the sensed position is its truth. The agent never reads these columns.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from pal.agent.history import History
from pal.agent.senses import Percept

__all__ = ["transition"]


def _truth(percept: Percept, o: str, d: int) -> np.ndarray | None:
    truth = percept.evaluation.get("truth")
    if isinstance(truth, Mapping) and o in truth:
        return np.asarray(truth[o], dtype=np.float64)[:d]
    m = percept.measurements.get(o)
    return m.position if m is not None and m.source == "sensed" else None


def transition(
    history: History,
    episode: int,
    first: bool,
    act: np.ndarray,
    prev: Percept,
    new: Percept,
    est_prev: Mapping[str, np.ndarray | None],
    est: Mapping[str, np.ndarray | None],
) -> dict[str, Any]:
    """The history row of the step ``prev -> new`` under ``act`` (the fields of ``history.fields``).

    Args:
        history: the store (its layout and, for momentum, its last row).
        episode: the episode index.
        first: the step is the first of its episode (objects start at rest).
        act: (A,) executed action.
        prev: the percept before the step.
        new: the percept after it.
        est_prev: object -> estimate before the step (None: unknown).
        est: object -> estimate after it.
    """
    objs, d = history.objects, history.object_dim
    nan = np.full(d, np.nan)

    def rows(values: list[Any]) -> np.ndarray:
        return np.array([nan if v is None else v for v in values], dtype=np.float64).reshape(len(objs), d)

    def pick(ms: Mapping[str, Any], attr: str = "position") -> np.ndarray:
        return rows([None if ms[o] is None else getattr(ms[o], attr) for o in objs])

    row = {
        "episode": episode,
        "act": act,
        "q_prev": prev.q,
        "q": new.q,
        "hand_prev": np.zeros(0) if prev.effector is None else prev.effector,
        "hand": np.zeros(0) if new.effector is None else new.effector,
        "touch": new.touch,
        "meas_prev": pick(prev.measurements),
        "meas": pick(new.measurements),
        "std": pick(new.measurements, "std"),
        "est_prev": rows([est_prev[o] for o in objs]),
        "est": rows([est[o] for o in objs]),
        "truth_prev": rows([_truth(prev, o, d) for o in objs]),
        "truth": rows([_truth(new, o, d) for o in objs]),
        "state": np.asarray(prev.evaluation.get("state", np.zeros(0)), dtype=np.float64),
    }
    if history.velocities:
        row["v_prev"], row["v"] = prev.v, new.v
    if history.momentum:  # each object's measured displacement over the step before this one
        last = len(history) - 1
        row["vel_prev"] = (
            np.zeros((len(objs), d))
            if first
            else history.array("meas")[last] - history.array("meas_prev")[last]
        )
    return row
