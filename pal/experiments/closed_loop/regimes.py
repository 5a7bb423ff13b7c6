"""Held-out object motion sorted into regimes: contact or none, random or planned pushes, with its coverage.

Every row is one transition of one object. Its predictive distribution of the displacement
``dpos.o`` over the step is :func:`inference.predictive_intervals` given the executed servo
targets, the joint angles and the sensed hand before the step and the object positions before
it (the model's source: perceived or true); the contact switch, the hand after the move and the
ensemble members are sampled (the unobserved ancestors), so where contact is uncertain the
interval is the mixture's. The draws are made once per object and read at every level of
``levels`` (a reliability curve) and at the reported level (90 %).

A row's regime is its contact label, the touch sensor's 0/1 (:func:`pal.agent.graph.contact_rule`
of the gated form, whatever form the model has), and its origin: ``"random"`` (babbling) or
``"planned"`` (the planner's actions). Coverage counts the components (x, y) separately: the
share of ``(row, component)`` pairs whose true displacement lies inside the interval; the sd is
the per-component sd of the draws (m).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import torch

from inference import coverage_by_regime, predictive_interval, predictive_intervals
from models import WorldModel
from pal.agent import ModelConfig, pushing_spec
from pal.agent.graph import contact_rule
from pal.agent.graph_frame import displacement_site
from pal.agent.history import History, contact_label
from pal.checks import check_float, check_int

__all__ = [
    "LEVEL",
    "LEVELS",
    "ORIGINS",
    "RegimeRows",
    "concat",
    "contact_coverage",
    "model_inputs",
    "regime_rows",
    "summarize",
]

#: The reported interval's probability.
LEVEL = 0.9
#: The nominal levels of the reliability curve (LEVEL among them).
LEVELS = (0.5, 0.6, 0.7, 0.8, 0.9, 0.95)
#: Where a row's action came from.
ORIGINS = ("random", "planned")
_CONTACT = {True: "contact", False: "no contact"}


@dataclass(frozen=True)
class RegimeRows:
    """Per-row predictive summaries of one or more objects' displacements (module docstring).

    Attributes:
        contact: ``(n,)`` bool, the touch sensor's contact over the step.
        origin: ``(n,)`` str, one of :data:`ORIGINS`.
        true: ``(n, d)`` the true displacement, m.
        mean: ``(n, d)`` the predictive mean, m.
        sd: ``(n, d)`` the predictive sd per component, m.
        inside: ``(L, n, d)`` bool, the true component inside the interval at ``levels[l]``.
        levels: the L nominal levels.
    """

    contact: np.ndarray
    origin: np.ndarray
    true: np.ndarray
    mean: np.ndarray
    sd: np.ndarray
    inside: np.ndarray
    levels: tuple[float, ...]

    def __post_init__(self) -> None:
        n = len(self.contact)
        shapes = (self.true.shape, self.mean.shape, self.sd.shape)
        if len(self.origin) != n or len(set(shapes)) != 1 or self.true.shape[0] != n:
            raise ValueError(
                f"contact ({n},), origin {self.origin.shape}, true, mean, sd {shapes} must have the same rows"
            )
        if self.inside.shape != (len(self.levels), *self.true.shape):
            raise ValueError(
                f"inside has shape {self.inside.shape}, expected {(len(self.levels), *self.true.shape)}"
            )
        bad = sorted(set(self.origin.tolist()) - set(ORIGINS))
        if bad:
            raise ValueError(f"origin has {bad}; expected values of {ORIGINS}")

    def __len__(self) -> int:
        return len(self.contact)

    def select(self, mask: np.ndarray) -> RegimeRows:
        """The rows where ``mask`` ``(n,)`` is true."""
        return RegimeRows(
            self.contact[mask],
            self.origin[mask],
            self.true[mask],
            self.mean[mask],
            self.sd[mask],
            self.inside[:, mask],
            self.levels,
        )


def concat(parts: Sequence[RegimeRows]) -> RegimeRows:
    """The rows of ``parts`` (same levels) in one :class:`RegimeRows`.

    Raises:
        ValueError: no parts, or parts of different levels.
    """
    if not parts:
        raise ValueError("concat needs at least one RegimeRows")
    levels = parts[0].levels
    if any(p.levels != levels for p in parts):
        raise ValueError(f"parts have different levels: {[p.levels for p in parts]}")
    cat = lambda key, axis=0: np.concatenate([getattr(p, key) for p in parts], axis)  # noqa: E731
    return RegimeRows(
        cat("contact"), cat("origin"), cat("true"), cat("mean"), cat("sd"), cat("inside", 1), levels
    )


def model_inputs(
    history: History, rows: np.ndarray, source: str = "truth"
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """The model's given values before each step of ``rows``, and which rows have them.

    Args:
        history: the agent's history.
        rows: ``(n,)`` history rows.
        source: object positions before the step from ``"perceived"`` (Π) or ``"truth"``.

    Returns:
        ``(values, ok)``: ``values`` maps ``act``, ``q_prev``, ``ee_prev`` and ``pos_prev.o`` to
        ``(n, dim)`` arrays; ``ok`` ``(n, O)`` is true where object o's position before the
        step is known (an unperceived object's position is filled with the true one, which
        only enters the rows that are not used).
    """
    if source not in ("perceived", "truth"):
        raise ValueError(f"source {source!r} unknown; expected 'perceived' or 'truth'")
    act, q_prev, hand_prev = (history.array(k)[rows] for k in ("act", "q_prev", "hand_prev"))
    truth_prev = history.array("truth_prev")[rows]
    prev = history.array("meas_prev")[rows] if source == "perceived" else truth_prev
    ok = np.isfinite(prev[..., 0])
    values = {"act": act, "q_prev": q_prev, "ee_prev": hand_prev}
    for k, o in enumerate(history.objects):
        values[f"pos_prev.{o}"] = np.where(ok[:, k, None], prev[:, k], truth_prev[:, k])
    return values, ok


def regime_rows(
    model: WorldModel,
    history: History,
    rows: np.ndarray,
    origin: str,
    *,
    source: str = "truth",
    levels: Sequence[float] = LEVELS,
    num_samples: int = 200,
    seed: int = 0,
) -> RegimeRows:
    """Every object's held-out rows of ``rows`` with their predictive summaries (module docstring).

    Args:
        model: a fitted pushing world model (gated or smooth displacement).
        history: the agent's history (with the simulator's truth, evaluation only).
        rows: ``(n,)`` history rows to evaluate.
        origin: where their actions came from, one of :data:`ORIGINS`.
        source: the object positions the model is given before the step (:func:`model_inputs`).
        levels: nominal levels of the intervals read from the draws.
        num_samples: draws per row of :func:`inference.predictive_intervals`.
        seed: seeds the draws.

    Returns:
        the objects' rows pooled, the rows of each object where its position before the
        step is known.
    """
    if origin not in ORIGINS:
        raise ValueError(f"origin {origin!r} unknown; expected one of {ORIGINS}")
    check_int("num_samples", num_samples, 2)
    levels = tuple(check_float("level", v, 0.0, 1.0, open_low=True, open_high=True) for v in levels)
    rows = np.asarray(rows, dtype=np.int64).reshape(-1)
    if rows.size == 0:
        raise ValueError("regime_rows needs at least one row; got none")
    values, ok = model_inputs(history, rows, source)
    truth_prev, truth, touch = (history.array(k)[rows] for k in ("truth_prev", "truth", "touch"))
    parts = []
    for k, o in enumerate(history.objects):
        keep = ok[:, k]
        if not keep.any():
            continue
        given = {n: torch.as_tensor(v[keep], dtype=model.dtype) for n, v in values.items()}
        site = displacement_site(model.graph, o)
        intervals = predictive_intervals(model, given, site, levels, num_samples, seed)
        true = (truth[keep, k] - truth_prev[keep, k]).astype(np.float64)
        inside = np.stack(
            [(true >= i.lower.double().numpy()) & (true <= i.upper.double().numpy()) for i in intervals]
        )
        parts.append(
            RegimeRows(
                contact=touch[keep, k] > 0,
                origin=np.full(int(keep.sum()), origin),
                true=true,
                mean=intervals[0].mean.double().numpy(),
                sd=intervals[0].sd.double().numpy(),
                inside=inside,
                levels=levels,
            )
        )
    if not parts:
        raise ValueError(f"no object's position before the step is known on the {rows.size} rows")
    return concat(parts)


def _regime(rows: RegimeRows, level: float) -> dict[str, Any]:
    n = len(rows)
    out: dict[str, Any] = {"rows": n, "components": int(rows.true.size)}
    if n == 0:
        return {**out, "coverage": None, "sd_median_mm": None, "reliability": None}
    reliability = {f"{v:g}": float(rows.inside[i].mean()) for i, v in enumerate(rows.levels)}
    out["coverage"] = reliability[f"{level:g}"]
    out["sd_median_mm"] = float(np.median(rows.sd)) * 1000
    out["abs_err_median_mm"] = float(np.median(np.abs(rows.mean - rows.true))) * 1000
    out["reliability"] = reliability
    return out


def summarize(rows: RegimeRows, level: float = LEVEL) -> dict[str, dict[str, Any]]:
    """Per regime: coverage at ``level``, median sd and |error| (mm), row count, the reliability curve.

    Regimes: ``"<origin> contact"`` and ``"<origin> no contact"`` for each origin present,
    ``"contact"`` and ``"no contact"`` over all origins, and ``"all"``. A regime without rows
    has ``None`` statistics and ``rows`` 0.

    Returns:
        regime -> ``{"rows", "components", "coverage", "sd_median_mm", "abs_err_median_mm",
        "reliability": {level: coverage}}``; coverage counts components separately.

    Raises:
        ValueError: ``level`` is not one of the rows' levels.
    """
    if not any(abs(level - v) < 1e-12 for v in rows.levels):
        raise ValueError(f"level {level!r} is not among the rows' levels {rows.levels}")
    out = {"all": _regime(rows, level)}
    for c in (True, False):
        out[_CONTACT[c]] = _regime(rows.select(rows.contact == c), level)
    for origin in ORIGINS:
        if not (rows.origin == origin).any():
            continue
        for c in (True, False):
            out[f"{origin} {_CONTACT[c]}"] = _regime(
                rows.select((rows.origin == origin) & (rows.contact == c)), level
            )
    return out


def contact_coverage(
    model: WorldModel,
    history: History,
    config: ModelConfig,
    rows: np.ndarray,
    *,
    level: float = 0.9,
    num_samples: int = 200,
    seed: int = 0,
    contact_given: bool = False,
) -> dict[str, dict[str, Any]]:
    """Coverage of the true displacements by the model's forward interval, on contact and no-contact rows.

    The interval is :func:`inference.predictive_interval` of ``dpos.o`` from the actions, joint
    angles, hand and true object positions before the step (the contact, hand and ensemble
    members sampled); all components must lie inside for a row to count. Rows are labelled by
    the gated form's rule (the touch sensor here), whatever the model's form. With
    ``contact_given`` the sensed contact is given to the model as well (the touch strength to a
    smooth model, the 0/1 switch to a gated one), so only the hand and the members are sampled.

    Returns:
        object -> ``{"contact": {"coverage", "rows"}, "no contact": {...}, "all": {...},
        "sd_no_contact_median_mm": the median predictive sd (norm over components) on no-contact rows}``.
    """
    rule, floor = contact_rule(pushing_spec(), replace(config, displacement="gated"))
    values = model_inputs(history, rows, "truth")[0]
    truth_prev, truth, touch = (history.array(k)[rows] for k in ("truth_prev", "truth", "touch"))
    given = contact_rule(pushing_spec(), config)[0]
    if contact_given:
        values.update(
            {
                f"contact.{o}": contact_label(touch[:, k], truth[:, k] - truth_prev[:, k], given)
                for k, o in enumerate(history.objects)
            }
        )
    out: dict[str, dict[str, Any]] = {}
    for k, o in enumerate(history.objects):
        interval = predictive_interval(
            model, values, displacement_site(model.graph, o), level=level, num_samples=num_samples, seed=seed
        )
        true = truth[:, k] - truth_prev[:, k]
        regime = contact_label(touch[:, k], true, rule, floor)[:, 0].astype(np.int64)
        res: dict[str, Any] = coverage_by_regime(
            true, interval.lower, interval.upper, regime, {0: "no contact", 1: "contact"}
        )
        sd = interval.sd.double().norm(dim=-1).numpy()
        res["sd_no_contact_median_mm"] = (
            float(np.median(sd[regime == 0]) * 1000) if (regime == 0).any() else None
        )
        out[o] = res
    return out
