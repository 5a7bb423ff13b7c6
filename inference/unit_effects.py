"""Unit-level effects of a binary treatment (the CATE) with intervals, from a fitted world model.

For a Bernoulli site T, a continuous descendant Y and the variables X that are not
descendants of T (see :mod:`inference.effects` for when ``m_t`` identifies the effect):

    tau(x_i) = m_1(x_i) - m_0(x_i),   m_t(x) = Y predicted under do(T = t) from x (expected residuals)

The interval comes from the members of the model's ensembles (:class:`models.EnsembleMechanism`,
``WorldModel(..., members=K)``), which :func:`inference.fit` trains on bootstrap resamples of
the rows: member k gives ``tau_k(x_i)``, and the interval is ``tau(x_i) +- z sd_k(tau_k(x_i))``,
a bootstrap standard error with a normal quantile. A model with one member carries no
estimate of its own error: its intervals have zero width, and ``UnitEffects.members`` is 1.

The rows need the variables X; the treatment and outcome columns are not read, so the
effects of new units can be asked for from their covariates alone.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from scipy.stats import norm

from models.checks import check_float
from models.tables import is_table
from models.world import WorldModel, as_values, require_world_model

__all__ = ["COLUMNS", "UnitEffects", "check_treatment_site", "unit_effects"]

#: the columns of :attr:`UnitEffects.table`
COLUMNS = ("effect", "low", "high", "y0", "y1")


@dataclass(frozen=True)
class UnitEffects:
    """Per-unit effects and their intervals.

    Attributes:
        effect, low, high: ``(N,)`` the effect ``m_1 - m_0`` and its ``level`` interval.
        y0, y1: ``(N,)`` the predicted outcomes under do(T = 0) and do(T = 1).
        level: the interval level.
        members: the ensemble members the interval was computed from (1: zero width).
        index: the row labels of the input DataFrame (None for other inputs).
    """

    effect: np.ndarray
    low: np.ndarray
    high: np.ndarray
    y0: np.ndarray
    y1: np.ndarray
    level: float
    members: int
    index: Any = None

    def table(self) -> Any:
        """A pandas DataFrame with :data:`COLUMNS` (the input's index) when the rows were a DataFrame, else column -> ``(N,)``."""
        columns = {c: getattr(self, c) for c in COLUMNS}
        if self.index is None:
            return columns
        import pandas as pd

        return pd.DataFrame(columns, index=self.index)

    def covers(self, effect: Any) -> float:
        """Share of units whose interval holds the given ``(N,)`` effects (e.g. known ones)."""
        truth = np.asarray(effect, dtype=np.float64).reshape(-1)
        if truth.shape != self.effect.shape:
            raise ValueError(f"effect has shape {truth.shape}, expected {self.effect.shape} (one per unit)")
        return float(np.mean((self.low <= truth) & (truth <= self.high)))


def check_treatment_site(model: WorldModel, treatment: Any, outcome: Any) -> set[str]:
    """Check that ``treatment`` is a Bernoulli non-root and ``outcome`` a continuous descendant; return the descendants.

    Raises:
        ValueError: a missing treatment (None), unknown names, a treatment that is not a
            Bernoulli site with parents, or an outcome that is not a continuous descendant.
    """
    if treatment is None:
        raise ValueError(
            "a treatment effect needs a treatment: got treatment=None; name the Bernoulli site whose "
            "effect is wanted (declared with discrete={name: 2})"
        )
    g = model.graph
    g.check_name(treatment, what="treatment")
    g.check_name(outcome, what="outcome")
    if model.categories(treatment) != 2 or g.is_root(treatment):
        raise ValueError(
            f"treatment {treatment!r} must be a Bernoulli site with parents (its mechanism is the "
            "propensity); declare it with discrete={name: 2} and give it its confounders as parents"
        )
    desc = g.descendants(treatment)
    if outcome not in desc or model.categories(outcome) is not None:
        raise ValueError(f"outcome {outcome!r} must be a continuous descendant of {treatment!r}")
    return set(desc)


def unit_effects(model: Any, data: Any, treatment: str, outcome: str, *, level: float = 0.9) -> UnitEffects:
    """The effect of do(T = 1) against do(T = 0) on ``outcome`` for every row (module docstring).

    Args:
        model: a fitted world model whose ``treatment`` site is a Bernoulli mechanism.
        data: name -> ``(N, dim)`` values or a table (a DataFrame keeps its index) of every
            variable that is not a descendant of the treatment.
        treatment: the treatment site.
        outcome: a continuous descendant of the treatment.
        level: interval level in (0, 1).

    Returns:
        :class:`UnitEffects`; ``.table()`` is a DataFrame when ``data`` was one.

    Raises:
        ValueError: see :func:`check_treatment_site`; missing columns or a bad ``level``.
    """
    model = require_world_model(model)
    level = check_float("level", level, minimum=0.0, maximum=1.0, min_open=True, max_open=True)
    desc = check_treatment_site(model, treatment, outcome)
    g = model.graph
    vals, n = as_values(g, data, what="data", dtype=model.dtype)
    missing = [v for v in g.names if v not in desc and v != treatment and v not in vals]
    if missing or n is None:
        raise ValueError(
            f"data needs columns for {missing} (every variable that is not a descendant of {treatment!r})"
        )
    given = {k: vals[k] for k in g.names if k not in desc and k != treatment}
    return _unit_effects(model, given, treatment, outcome, n, level, _index(data))


def _index(data: Any) -> Any:
    """The row labels of a DataFrame, else None."""
    if is_table(data) and hasattr(data, "index") and hasattr(data, "iloc"):
        return data.index
    return None


def _unit_effects(
    model: WorldModel,
    given: dict[str, torch.Tensor],
    treatment: str,
    outcome: str,
    n: int,
    level: float,
    index: Any,
) -> UnitEffects:
    """``m_1 - m_0`` per member and unit, then the mean and the bootstrap interval."""
    k = model.ensemble_size
    arms = []
    with torch.no_grad():
        for arm in (0.0, 1.0):
            pred = model.predict(
                {**given, treatment: torch.full((n, 1), arm, dtype=model.dtype)}, members=k > 1
            )
            y = pred[outcome][..., 0].double()
            arms.append(y if k > 1 else y.unsqueeze(0))  # (K, N)
    per_member = arms[1] - arms[0]
    effect = per_member.mean(0)
    sd = per_member.std(0) if k > 1 else torch.zeros_like(effect)
    z = float(norm.ppf(0.5 + level / 2))
    out = {name: t.numpy() for name, t in (("y0", arms[0].mean(0)), ("y1", arms[1].mean(0)))}
    return UnitEffects(
        effect.numpy(),
        (effect - z * sd).numpy(),
        (effect + z * sd).numpy(),
        out["y0"],
        out["y1"],
        level,
        k,
        index,
    )
