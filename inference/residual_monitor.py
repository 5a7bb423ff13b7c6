"""The residual monitor of the world model's meta-learning (Eq. 4.50, thesis §4.3.6).

Per variable X_i it keeps the windowed mean

    m_i(t) = (1 / W) * sum_{tau = t-W}^{t-1} ||u_i(tau)||^2,   u_i = (x_i - f_i(pa_i)) / s_i,

with s_i a reference scale: a per-variable tolerance when given (the error the agent can
accept), else sigma_i of the model when the monitor was made. A variable is *flagged* when
m_i exceeds ``threshold`` x dim_i after ``patience`` consecutive updates (each after a refit);
:func:`inference.metalearn.revise` then tests structural revisions of it.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import torch

from models.checks import as_float_tensor, check_float, check_int, check_mapping, describe
from models.world import WorldModel, as_values, require_world_model

__all__ = ["ResidualMonitor"]


class ResidualMonitor:
    """Windowed mean squared standardised residuals per variable (Eq. 4.50).

    Args:
        model: the world model whose non-roots are monitored.
        window: W, rows in the window.
        tolerance: optional non-root name -> reference sd s_i > 0 (the variable's units;
            a scalar or ``(dim,)``); default sigma_i.
        threshold: a variable is high when m_i > threshold * dim_i (> 0).
        patience: consecutive high updates before it is flagged.
    """

    def __init__(
        self,
        model: WorldModel,
        window: int = 1000,
        tolerance: Mapping[str, float] | None = None,
        threshold: float = 2.0,
        patience: int = 2,
    ) -> None:
        model = require_world_model(model)
        window = check_int("window", window, minimum=1)
        threshold = check_float("threshold", threshold, minimum=0.0, min_open=True)
        patience = check_int("patience", patience, minimum=1)
        self.window, self.threshold, self.patience = window, threshold, patience
        tol = dict(check_mapping("tolerance", tolerance, allow_none=True))
        scales = {}
        for name, value in tol.items():
            model.graph.check_name(name, what="tolerance variable")
            if model.graph.is_root(name):
                raise ValueError(f"tolerance names {name!r}, a root; only non-roots are monitored")
            t = as_float_tensor(value, f"tolerance[{name!r}]", model.dtype).detach().reshape(-1)
            dim = model.graph[name].dim
            if t.numel() == 1:
                t = t.expand(dim)
            if t.numel() != dim or not bool((torch.isfinite(t) & (t > 0)).all()):
                raise ValueError(
                    f"tolerance[{name!r}] must be {dim} finite values > 0 (or one), got {describe(value)}"
                )
            scales[name] = t.clone()
        self.scale = {
            n: scales[n] if n in scales else model.sigma(n).detach().clone() for n in model.graph.non_roots
        }
        self.dims = {n: model.graph[n].dim for n in model.graph.non_roots}
        self.history: dict[str, list[float]] = {n: [] for n in self.scale}
        self.levels: dict[str, list[float]] = {n: [] for n in self.scale}

    def update(self, model: WorldModel, values: Mapping[str, Any]) -> dict[str, float]:
        """Add rows (name -> ``(N, dim)`` for every variable) and return m_i per monitored variable."""
        model = require_world_model(model)
        vals, _ = as_values(model.graph, values, what="values", dtype=model.dtype)
        missing = [v for v in model.graph.names if v not in vals]
        if missing:
            raise ValueError(f"values needs rows of every variable; missing {missing}")
        out = {}
        with torch.no_grad():
            for name in self.scale:
                if name not in model.graph or model.graph.is_root(name):
                    continue
                u = (vals[name] - model.loc(name, vals)) / self.scale[name]
                self.history[name] = (self.history[name] + u.pow(2).sum(-1).tolist())[-self.window :]
                out[name] = float(np.mean(self.history[name]))
                self.levels[name].append(out[name])
        return out

    def state(self) -> dict[str, Any]:
        """The monitor as JSON-ready data (settings, scales, windows, levels); :meth:`from_state` inverts it."""
        return {
            "window": self.window,
            "threshold": self.threshold,
            "patience": self.patience,
            "scale": {n: [float(v) for v in t.tolist()] for n, t in self.scale.items()},
            "history": {n: list(v) for n, v in self.history.items()},
            "levels": {n: list(v) for n, v in self.levels.items()},
        }

    @classmethod
    def from_state(cls, model: WorldModel, state: Mapping[str, Any]) -> ResidualMonitor:
        """The monitor of :meth:`state` for ``model`` (its scales become the tolerances).

        Raises:
            ValueError: a state whose variables are not ``model``'s non-roots (names them).
        """
        names = set(state["scale"])
        if (
            names != set(model.graph.non_roots)
            or set(state["history"]) != names
            or set(state["levels"]) != names
        ):
            raise ValueError(
                f"monitor state covers {sorted(names)}, but the model's non-roots are {sorted(model.graph.non_roots)}"
            )
        out = cls(model, state["window"], state["scale"], state["threshold"], state["patience"])
        out.history = {n: [float(v) for v in state["history"][n]] for n in out.scale}
        out.levels = {n: [float(v) for v in state["levels"][n]] for n in out.scale}
        return out

    def flagged(self) -> list[str]:
        """Variables whose last ``patience`` levels all exceed threshold * dim."""
        return [
            n
            for n, lv in self.levels.items()
            if len(lv) >= self.patience
            and all(v > self.threshold * self.dims[n] for v in lv[-self.patience :])
        ]
