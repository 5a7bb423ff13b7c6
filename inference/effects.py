"""Average effects of a binary treatment from a fitted world model (ATE and ATT).

For a Bernoulli site T (the treatment) and a continuous outcome Y of a fitted
:class:`models.WorldModel`, with X the variables that are not descendants of T:

    m_t(x) = Y predicted under do(T = t) from x, expected residuals   (the outcome model)
    e(x)   = P(T = 1 | pa_T(x)), the treatment's own Bernoulli mechanism (the propensity)

``m_t`` is ``E[Y | do(T = t), x]`` when the descendants of T between T and Y are linear in
their parents' noise (always so when Y reads T and X directly, as in X -> T -> Y, X -> Y);
then the parents of T (more generally X) block every back-door path of the graph.

Estimators (``estimator=``), over the N rows of ``data``:

* ``"standardise"`` (the g-formula): ATE = mean_i [m_1(x_i) - m_0(x_i)]; ATT = mean over the
  treated of [y_i - m_0(x_i)], which is y_i minus the unit's counterfactual outcome under
  do(T = 0) with its abducted noise (Eq. 4.43) for additive-noise outcomes.
* ``"doubly_robust"`` (augmented inverse propensity weighting): consistent when either the
  outcome model or the propensity is right,

      ATE = mean_i [ m_1 - m_0 + t_i (y_i - m_1) / e_i - (1 - t_i) (y_i - m_0) / (1 - e_i) ]
      ATT = [ sum_i t_i (y_i - m_0) - sum_i (1 - t_i) e_i / (1 - e_i) (y_i - m_0) ] / sum_i t_i

Beside the average, :attr:`EffectResult.units` holds every row's own effect
``m_1(x_i) - m_0(x_i)`` (the CATE) with an interval (:mod:`inference.unit_effects`).

The interval is ``estimate +- z sd(psi) / sqrt(N)`` from the estimator's influence function
psi (normal approximation; the fitted models are taken as given). Propensities are clipped
to ``[clip, 1 - clip]``; :attr:`EffectResult.clipped` counts the units that were.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from scipy.stats import norm
from torch import Tensor

from inference.unit_effects import UnitEffects, _index, _unit_effects, check_treatment_site
from models.checks import check_choice, check_float
from models.world import WorldModel, as_values, require_world_model

__all__ = ["ESTIMATORS", "EffectResult", "treatment_effect"]

ESTIMATORS = ("standardise", "doubly_robust")
TARGETS = ("ate", "att")


@dataclass(frozen=True)
class EffectResult:
    """An average treatment effect and its interval.

    Attributes:
        estimate: the effect, in the outcome's units.
        low, high: the ``level`` interval.
        se: standard error from the influence function.
        level: interval level.
        target: ``"ate"`` or ``"att"``.
        estimator: a key of :data:`ESTIMATORS`.
        n, treated: rows used and treated rows among them.
        clipped: units whose propensity was clipped (0 for standardisation).
        naive: difference of the mean outcomes of treated and untreated rows.
        clip: the bound: propensities were clipped to ``[clip, 1 - clip]``.
        units: every row's effect and interval (:class:`inference.unit_effects.UnitEffects`;
            ``units.table()`` is a DataFrame when the data were one).
    """

    estimate: float
    low: float
    high: float
    se: float
    level: float
    target: str
    estimator: str
    n: int
    treated: int
    clipped: int
    naive: float
    clip: float = 1e-3
    units: UnitEffects | None = None

    def covers(self, value: float) -> bool:
        """Whether ``value`` lies in the interval."""
        return self.low <= value <= self.high

    def to_dict(self) -> dict[str, Any]:
        """JSON-compatible fields (the unit effects as lists)."""
        out = {k: v for k, v in self.__dict__.items() if k != "units"}
        if self.units is not None:
            out["units"] = {k: np.asarray(v).tolist() for k, v in self.units.table().items()}
        return out


def treatment_effect(
    model: WorldModel,
    data: Any,
    treatment: str,
    outcome: str,
    *,
    target: str = "ate",
    estimator: str = "doubly_robust",
    level: float = 0.9,
    clip: float = 1e-3,
) -> EffectResult:
    """Average effect of the Bernoulli ``treatment`` on ``outcome`` (module docstring).

    Args:
        model: a fitted world model whose ``treatment`` site is a Bernoulli mechanism.
        data: name -> ``(N, dim)`` values (or a table) of the treatment, the outcome and every
            variable that is not a descendant of the treatment.
        treatment: the treatment site (codes 0/1).
        outcome: a continuous descendant of the treatment.
        target: ``"ate"`` (all units) or ``"att"`` (the treated).
        estimator: ``"standardise"`` or ``"doubly_robust"``.
        level: interval level in (0, 1).
        clip: propensities are clipped to ``[clip, 1 - clip]``, in (0, 0.5).

    Returns:
        :class:`EffectResult`.

    Raises:
        ValueError: the treatment is not a Bernoulli non-root, the outcome is not a
            continuous descendant of it, missing columns, codes other than 0/1, rows with
            one arm only, or a setting out of range.
    """
    model = require_world_model(model)
    target = check_choice("target", target, TARGETS)
    estimator = check_choice("estimator", estimator, ESTIMATORS)
    level = check_float("level", level, minimum=0.0, maximum=1.0, min_open=True, max_open=True)
    clip = check_float("clip", clip, minimum=0.0, maximum=0.5, min_open=True, max_open=True)
    desc = check_treatment_site(model, treatment, outcome)
    g = model.graph
    vals, n = _check_rows(model, data, treatment, outcome, desc)
    t, y = vals[treatment][:, 0].double(), vals[outcome][:, 0].double()
    n_t = int(t.sum())
    given = {k: vals[k] for k in g.names if k not in desc}
    m = {}
    with torch.no_grad():
        for arm in (0, 1):
            # a given value replaces the mechanism, as do(T = arm) does
            pred = model.predict({**given, treatment: torch.full((n, 1), float(arm), dtype=model.dtype)})
            m[arm] = pred[outcome][:, 0].double()
        e_raw = model.probs(treatment, given)[:, 1].double()
    e = e_raw.clamp(clip, 1 - clip)
    clipped = int(((e_raw < clip) | (e_raw > 1 - clip)).sum()) if estimator == "doubly_robust" else 0
    psi = _influence(t, y, m[0], m[1], e, target, estimator)
    estimate = float(psi.mean())
    if target == "att":  # psi was scaled by N / n_t; centre the ratio estimator's influence function
        psi = psi - t * estimate * n / n_t
    se = float(psi.std() / math.sqrt(n))
    z = float(norm.ppf(0.5 + level / 2))
    naive = float(y[t == 1].mean() - y[t == 0].mean())
    units = _unit_effects(model, given, treatment, outcome, n, level, _index(data))
    return EffectResult(
        estimate,
        estimate - z * se,
        estimate + z * se,
        se,
        level,
        target,
        estimator,
        n,
        n_t,
        clipped,
        naive,
        clip,
        units=units,
    )


def _check_rows(
    model: WorldModel, data: Any, treatment: str, outcome: str, desc: set[str]
) -> tuple[dict[str, Tensor], int]:
    """The rows as tensors, with the treatment, the outcome, every non-descendant and both arms."""
    g = model.graph
    vals, n = as_values(g, data, what="data", dtype=model.dtype)
    needed = [v for v in g.names if v not in desc] + [outcome]
    missing = [v for v in needed if v not in vals]
    if missing or n is None:
        raise ValueError(
            f"data needs columns for {missing} (the treatment, the outcome and every non-descendant)"
        )
    _check_binary(vals[treatment], treatment)
    model.check_codes(vals, "data")
    n_t = int(vals[treatment].sum())
    if n_t == 0 or n_t == n:
        raise ValueError(f"data has {n_t} treated rows of {n}; both arms are needed")
    return vals, n


def _check_binary(column: Tensor, treatment: str) -> None:
    """Refuse a treatment column with a value other than 0 and 1, naming it."""
    values = torch.unique(column)
    other = values[(values != 0) & (values != 1)]
    if other.numel():
        raise ValueError(
            f"treatment column {treatment!r} has the value {float(other[0]):g} "
            f"(values: {[float(v) for v in values[:6]]}); a binary treatment takes 0 and 1 only"
        )


def _influence(
    t: Tensor, y: Tensor, m0: Tensor, m1: Tensor, e: Tensor, target: str, estimator: str
) -> Tensor:
    """Per-unit terms whose mean is the estimate: ``(N,)``."""
    n, n_t = t.shape[0], float(t.sum())
    if target == "ate":
        if estimator == "standardise":
            return m1 - m0
        return m1 - m0 + t * (y - m1) / e - (1 - t) * (y - m0) / (1 - e)
    if estimator == "standardise":
        return t * (y - m0) * n / n_t
    w = e / (1 - e)
    control = (1 - t) * w * (y - m0)
    # normalised weights: the control term sums to the weighted mean residual of the controls
    scale = n_t / float(((1 - t) * w).sum())
    return (t * (y - m0) - scale * control) * n / n_t
