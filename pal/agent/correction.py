"""Online correction from abducted residuals: the residual modes of Alg. 4.1 used to act.

A fitted model is biased where the body differs from its training data. After each executed
transition the agent knows every arm variable of it (``q_prev, v_prev, ee_prev, act`` and the
realized ``dq, v, dee``), so the exogenous noise of each site is abducted exactly (the
abduction step of a counterfactual, Eq. 4.43):

    u_t = (x_t - f(pa_t)) / sigma(pa_t)                    per site, (dim,)

Over the last ``k = window`` executed transitions their mean ``ubar_t`` is filtered,

    uhat_t = uhat_{t-1} + g (ubar_t - uhat_{t-1}),         uhat_0 = 0, g = ``gain``,

and the planner's rollouts replay ``uhat_t`` on every step instead of the expected residual 0,
``x = f(pa) + sigma(pa) uhat_t`` (prediction with abducted noise carried forward: the
counterfactual "had this step's noise been the recent one"). A constant bias ``b = sigma u*`` of
a site then gives ``uhat_n = (1 - (1 - g)^n) u*`` after n steps, and the remaining offset of a
controller that cancels the predicted error falls as ``(1 - g)^n b`` (the closed form the tests
hold). The estimate starts at 0 in every episode and after every refit. ``enabled=False``
switches it off for comparison.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping

import numpy as np
import torch

from models import WorldModel
from pal.agent.config import CorrectionConfig
from pal.agent.senses import Percept

__all__ = ["Correction", "abduct", "realized"]


def abduct(
    model: WorldModel, values: Mapping[str, np.ndarray], sites: tuple[str, ...]
) -> dict[str, np.ndarray]:
    """The exact standardised residual ``u = (x - f(pa)) / sigma(pa)`` of each site, (dim,).

    Args:
        model: the world model.
        values: name -> (dim,) realized values of the sites and their parents.
        sites: the continuous sites to abduct (those of ``model`` whose values are all given).

    Raises:
        ValueError: a site that is not in the model, or a missing value.
    """
    out = {}
    graph = model.graph
    for s in sites:
        if s not in graph:
            raise ValueError(f"site {s!r} is not in the model; it has {list(graph.names)}")
        need = [s, *graph.parents(s)]
        missing = [n for n in need if n not in values]
        if missing:
            raise ValueError(f"abducting {s!r} needs the values of {missing}")
        pa = torch.cat(
            [
                torch.as_tensor(np.asarray(values[p]), dtype=model.dtype).reshape(1, -1)
                for p in graph.parents(s)
            ],
            -1,
        )
        with torch.no_grad():
            loc, scale = model.mechanism(s).loc_scale(pa)
        x = torch.as_tensor(np.asarray(values[s]), dtype=model.dtype).reshape(1, -1)
        out[s] = ((x - loc) / scale)[0].numpy().astype(np.float64)
    return out


def realized(
    before: Mapping[str, np.ndarray], action: np.ndarray, new: Percept, periodic: bool = False
) -> dict[str, np.ndarray]:
    """The arm values of one executed transition: the roots before, ``act``, and ``dq, q, v, dee, ee``.

    With ``periodic`` (angles from cos/sin) ``dq`` is wrapped into [-pi, pi).
    """
    out = {k: np.asarray(v, dtype=np.float64) for k, v in before.items()}
    out["act"] = np.asarray(action, dtype=np.float64)
    dq = new.q - out["q_prev"]
    out["q"], out["dq"] = new.q, ((dq + np.pi) % (2 * np.pi) - np.pi) if periodic else dq
    if new.v is not None:
        out["v"] = new.v
    if new.effector is not None and "ee_prev" in out:
        out["ee"], out["dee"] = new.effector, new.effector - out["ee_prev"]
    return out


class Correction:
    """The filtered residual estimate of the module docstring.

    Args:
        config: ``enabled``, ``window`` (k), ``gain`` (g) and the ``sites`` corrected.

    Attributes:
        estimate: site -> (dim,) the current uhat.
        steps: transitions observed since the last reset.
    """

    def __init__(self, config: CorrectionConfig) -> None:
        if not isinstance(config, CorrectionConfig):
            raise ValueError(f"config must be a CorrectionConfig, got {type(config).__name__}")
        self.config = config
        self.reset()

    def reset(self) -> None:
        """Forget the residuals (a new episode, a refitted model)."""
        self.window: deque[dict[str, np.ndarray]] = deque(maxlen=self.config.window)
        self.estimate: dict[str, np.ndarray] = {}
        self.steps = 0

    def update(self, residuals: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Take one transition's abducted residuals (site -> (dim,)) and return the new uhat."""
        self.window.append({k: np.asarray(v, dtype=np.float64) for k, v in residuals.items()})
        g = self.config.gain
        for s in residuals:
            mean = np.mean([r[s] for r in self.window if s in r], axis=0)
            prev = self.estimate.get(s, np.zeros_like(mean))
            self.estimate[s] = prev + g * (mean - prev)
        self.steps += 1
        return dict(self.estimate)

    def observe(
        self,
        model: WorldModel,
        before: Mapping[str, np.ndarray],
        action: np.ndarray,
        new: Percept,
        periodic: bool = False,
    ) -> None:
        """Abduct the sites of one executed transition (``before``: the graph's roots then) and update."""
        if not self.config.enabled:
            return
        values = realized(before, action, new, periodic)
        sites = tuple(s for s in self.config.sites if s in model.graph and s in values)
        self.update(abduct(model, values, sites))

    def noise(self, model: WorldModel) -> dict[str, np.ndarray] | None:
        """Site -> (dim,) residual to replay in the rollouts, or None (off, or nothing observed yet)."""
        if not self.config.enabled or not self.estimate:
            return None
        return {s: u for s, u in self.estimate.items() if s in model.graph}
