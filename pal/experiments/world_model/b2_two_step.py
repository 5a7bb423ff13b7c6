"""B2's two-step protocol: act, abduct the step's noise, act again from the same state (a counterfactual).

The one-shot protocol of the thesis executes the inferred action ``a_1`` once. Here the
realized displacement of that step gives the exact exogenous noise of the ``dq`` site,

    u = (dq_1 - f(pa_1)) / sigma(pa_1),       pa_1 = (a_1, q_prev [, dq_prev | v_prev]),

and the action is inferred again for the same target from the same recorded state with that
noise replayed in the prediction, ``dq = f(a, ...) + sigma(a, ...) u`` (the counterfactual
"which action would have reached the target, given what this state's step did"), then executed
from the restored state. Both protocols are reported.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from models import WorldModel
from pal.experiments.world_model.setup import ActionConfig, Prepared, infer_actions

__all__ = ["abducted_dq", "two_step"]


def abducted_dq(model: WorldModel, values: dict[str, np.ndarray], site: str) -> np.ndarray:
    """``u = (x - f(pa)) / sigma(pa)`` of ``site`` per row, ``(n, 1)``, from realized ``values`` (name -> ``(n, 1)``)."""
    parents = model.graph.parents(site)
    pa = torch.cat(
        [
            torch.as_tensor(np.asarray(values[p], np.float64).reshape(-1, 1), dtype=model.dtype)
            for p in parents
        ],
        -1,
    )
    with torch.no_grad():
        loc, scale = model.mechanism(site).loc_scale(pa)
    x = torch.as_tensor(np.asarray(values[site], np.float64).reshape(-1, 1), dtype=model.dtype)
    return ((x - loc) / scale).numpy().astype(np.float64)


def two_step(
    prep: Prepared,
    model: WorldModel,
    rows: np.ndarray,
    target: np.ndarray,
    state: dict[str, np.ndarray],
    first: tuple[np.ndarray, np.ndarray],
    action: ActionConfig,
    seed: int,
) -> dict[str, Any]:
    """The second action's realized angle ``(n,)``, rad, and the abducted noise ``(n, 1)``.

    Args:
        prep: the protocol's data and realizer.
        model: a fitted graph.
        rows: ``(n,)`` test rows.
        target: ``(n,)`` target angles, rad.
        state: the model's non-action roots at those rows (name -> ``(n, 1)``).
        first: ``(actions (n,), realized q (n,))`` of the one-shot protocol.
        action: the inference settings (they need a sampling stage: residuals replay in the torch twin).
        seed: seeds the sampling stage.
    """
    act, q_prev, dq, _ = prep.joint.names
    a1, q1 = first
    values = {
        **state,
        act: a1.reshape(-1, 1),
        dq: (q1 - np.asarray(state[q_prev]).reshape(-1)).reshape(-1, 1),
    }
    u = abducted_dq(model, values, dq)
    a2, _, _ = infer_actions(model, prep.joint, state, target, action, seed=seed + 1, noise={dq: u})
    return {"real": prep.realizer.outcomes(rows, a2), "noise": u}
