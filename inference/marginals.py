"""Rank transforms of skewed or heavy-tailed columns before structure learning.

The held-out score of :mod:`inference.crossfit` is a Gaussian likelihood of additive
residuals. A skewed reading (a log-normal-like quantity, an instrument saturated at the top
of its range) or heavy-tailed noise makes a few rows dominate that likelihood, so edges are
found or lost on outliers. The normal-score transform

    x -> Phi^-1( (rank(x) - 1/2) / N ),    ties given their mean rank,

keeps each column's order (so every monotone dependence stays) and makes its marginal
Gaussian. ``"auto"`` applies it to the columns whose sample skewness exceeds ``SKEW`` in
magnitude or whose excess kurtosis exceeds ``KURTOSIS``, and leaves the others as they are:
a rank transform bends exact additive relations (a body's ``q = q_prev + dq``, whose angles
are mildly skewed by the joint limits), so only strong departures from a Gaussian pay for it.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from scipy.special import ndtri
from scipy.stats import rankdata

from models.checks import as_float_array, check_choice

__all__ = ["KURTOSIS", "SKEW", "TRANSFORMS", "normal_scores", "skewed", "transform_columns"]

TRANSFORMS = ("auto", "rank", "none")

#: ``"auto"`` thresholds: |skewness| and excess kurtosis above which a column is rank transformed.
SKEW, KURTOSIS = 2.0, 6.0


def normal_scores(x: np.ndarray) -> np.ndarray:
    """The normal scores of each column of ``x`` ``(N, k)``: ``(N, k)`` float64 (module docstring)."""
    n = x.shape[0]
    return ndtri((rankdata(x, axis=0) - 0.5) / n)


def skewed(x: np.ndarray) -> np.ndarray:
    """``(k,)`` bool: the columns of ``x`` ``(N, k)`` that ``"auto"`` transforms (constant columns: False)."""
    big = np.abs(x).max(0)
    x = x / np.where(big > 0, big, 1.0)  # skewness and kurtosis do not depend on the units
    centred = x - x.mean(0)
    sd = centred.std(0)
    z = centred / np.where(sd > 0, sd, 1.0)
    skew, kurt = (z**3).mean(0), (z**4).mean(0) - 3.0
    return (sd > 0) & ((np.abs(skew) > SKEW) | (kurt > KURTOSIS))


def transform_columns(data: Mapping[str, object], how: str) -> tuple[dict[str, object], tuple[str, ...]]:
    """``data`` with its skewed (``"auto"``) or all (``"rank"``) columns as normal scores.

    Returns the new mapping (columns as ``(N, dim)`` float64 where transformed, the others as
    given) and the names of the variables with a transformed component.
    """
    how = check_choice("transform", how, TRANSFORMS)
    if how == "none":
        return dict(data), ()
    out: dict[str, object] = dict(data)
    changed = []
    for name, column in data.items():
        a = as_float_array(column, f"data[{name!r}]")
        if a.ndim != 2 or not np.isfinite(a).all():
            continue  # StructureData.build refuses it with the full message
        pick = np.ones(a.shape[1], dtype=bool) if how == "rank" else skewed(a)
        pick &= a.max(0) > a.min(0)  # not constant
        if pick.any():
            a = a.astype(np.float64, copy=True)
            a[:, pick] = normal_scores(a[:, pick])
            out[name] = a
            changed.append(name)
    return out, tuple(changed)
