"""A site's predictive distribution with its unobserved ancestors sampled, and coverage per regime.

:func:`predictive_interval` samples the program forward from the given values: every site that
is not given is drawn from its mechanism, residual and all (a latent switch from its
probabilities, a latent continuous ancestor from ``loc + scale * eps``), and each draw runs
through one component of each ensemble's calibrated mixture, the members in equal shares
(:meth:`models.WorldModel.predict` with ``members=True``; component k is member k shrunk toward
the member mean by the site's recalibration factor, so the draws have the site's calibrated
variance, :meth:`models.ensemble.EnsembleMechanism.mixture_members`). The draws of the asked site give, per row, the equal-tailed interval at
``level``, the mean and the sd: the total predictive spread, aleatoric, epistemic and that of
the unobserved ancestors. ``predict_scale`` by contrast gives the site's own scale at its
parents' expected values.

:func:`coverage_by_regime` counts how often the truth falls inside such intervals, separately
on the rows of each regime (e.g. contact and no contact).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor

__all__ = ["PredictiveInterval", "coverage_by_regime", "predictive_interval", "predictive_intervals"]

#: Rows times draws evaluated in one forward pass (bounds the memory of a call).
CHUNK = 1 << 18


@dataclass(frozen=True)
class PredictiveInterval:
    """Per row ``(N, dim)``: the interval ``[lower, upper]`` at ``level``, the mean and the sd of the draws."""

    lower: Tensor
    upper: Tensor
    mean: Tensor
    sd: Tensor
    level: float
    num_samples: int


def _check(level: Any, num_samples: Any, seed: Any) -> None:
    if isinstance(level, bool) or not isinstance(level, (int, float)) or not 0.0 < float(level) < 1.0:
        raise ValueError(f"level must be a number in (0, 1), got {level!r}")
    if isinstance(num_samples, bool) or not isinstance(num_samples, int) or num_samples < 2:
        raise ValueError(f"num_samples must be an int >= 2, got {num_samples!r}")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ValueError(f"seed must be a non-negative int, got {seed!r}")


def _draws(
    model: Any, values: Mapping[str, Tensor], site: str, n: int, num_samples: int, seed: int
) -> Tensor:
    """``(num_samples * K, N, dim)`` forward draws of ``site``."""
    generator = torch.Generator().manual_seed(seed)
    per = max(1, min(num_samples, CHUNK // max(n, 1)))
    out = []
    done = 0
    while done < num_samples:
        s = min(per, num_samples - done)
        rep = {k: v.repeat(s, *([1] * (v.ndim - 1))) for k, v in values.items()}
        with torch.no_grad():
            x = model.predict(rep, noise="sampled", generator=generator, members=True)[site]
        out.append(x.reshape(x.shape[0] * s, n, -1))
        done += s
    return torch.cat(out, 0)


def predictive_interval(
    model: Any,
    values: Mapping[str, Any],
    site: str,
    level: float = 0.9,
    num_samples: int = 1000,
    seed: int = 0,
) -> PredictiveInterval:
    """The predictive distribution of ``site`` given ``values``, its unobserved ancestors sampled (module docstring).

    Args:
        model: a :class:`models.WorldModel`.
        values: name -> ``(N, dim)``; every root, and any other site held at a given value.
        site: the site whose distribution is asked; not among ``values``.
        level: the interval's probability, in (0, 1).
        num_samples: forward draws per row (times the ensemble size K), >= 2.
        seed: seeds the draws.

    Returns:
        a :class:`PredictiveInterval` of ``(N, dim)`` tensors.

    Raises:
        ValueError: an unknown site or one given in ``values``, a bad level, number of samples
            or seed, or values that :meth:`models.WorldModel.predict` refuses.
    """
    return predictive_intervals(model, values, site, (level,), num_samples, seed)[0]


def predictive_intervals(
    model: Any,
    values: Mapping[str, Any],
    site: str,
    levels: Sequence[float],
    num_samples: int = 1000,
    seed: int = 0,
) -> tuple[PredictiveInterval, ...]:
    """:func:`predictive_interval` at several ``levels`` from one set of draws (e.g. a reliability curve).

    The interval at a level equals ``predictive_interval(..., level, num_samples, seed)``: the
    draws are made once and read at each level's equal-tailed quantiles.

    Returns:
        one :class:`PredictiveInterval` per level, in the order of ``levels``.

    Raises:
        ValueError: as :func:`predictive_interval`, or an empty ``levels``.
    """
    levels = tuple(levels)
    if not levels:
        raise ValueError("levels is empty; give at least one level in (0, 1)")
    for level in levels:
        _check(level, num_samples, seed)
    if site not in model.graph:
        raise ValueError(f"site {site!r} is not in the model; it has {list(model.graph.names)}")
    if site in values:
        raise ValueError(f"site {site!r} is given in values; its predictive distribution is its value")
    vals = {k: torch.as_tensor(v, dtype=model.dtype) for k, v in values.items()}
    n = next(iter(vals.values())).shape[0] if vals else 0
    draws = _draws(model, vals, site, n, num_samples, seed)
    ordered, _ = torch.sort(draws, 0)
    total = ordered.shape[0]
    mean, sd = draws.mean(0), draws.std(0)
    out = []
    for level in levels:
        tail = (1.0 - float(level)) / 2.0
        lo, hi = round(tail * (total - 1)), round((1.0 - tail) * (total - 1))
        out.append(
            PredictiveInterval(
                lower=ordered[lo],
                upper=ordered[hi],
                mean=mean,
                sd=sd,
                level=float(level),
                num_samples=num_samples,
            )
        )
    return tuple(out)


def coverage_by_regime(
    truth: Any, lower: Any, upper: Any, regime: Any, names: Mapping[int, str] | None = None
) -> dict[str, dict[str, float]]:
    """The share of rows whose truth lies in ``[lower, upper]`` (all components), per regime.

    Args:
        truth: ``(N, dim)`` (or ``(N,)``) the true values.
        lower: ``(N, dim)`` the intervals' lower ends.
        upper: ``(N, dim)`` their upper ends.
        regime: ``(N,)`` integer labels of the rows (e.g. 1 contact, 0 no contact).
        names: label -> name in the result (default ``{0: "off", 1: "on"}``, else the label).

    Returns:
        name -> ``{"coverage": share, "rows": n}`` for each regime present, and ``"all"``.

    Raises:
        ValueError: shapes that differ, NaN, or an empty input.
    """
    t, lo, hi = (torch.as_tensor(a, dtype=torch.float64) for a in (truth, lower, upper))
    t, lo, hi = (a.reshape(a.shape[0], -1) if a.ndim else a for a in (t, lo, hi))
    r = torch.as_tensor(regime).reshape(-1)
    if t.ndim != 2 or t.shape != lo.shape or t.shape != hi.shape or r.shape[0] != t.shape[0]:
        raise ValueError(
            f"truth {tuple(t.shape)}, lower {tuple(lo.shape)}, upper {tuple(hi.shape)} and regime "
            f"{tuple(r.shape)} must have the same rows (and truth, lower, upper the same shape)"
        )
    if t.shape[0] == 0:
        raise ValueError("coverage needs at least one row; got none")
    if bool(torch.isnan(t).any() | torch.isnan(lo).any() | torch.isnan(hi).any()):
        raise ValueError("truth, lower and upper must not hold NaN")
    inside = ((t >= lo) & (t <= hi)).all(1)
    label = {0: "off", 1: "on", **dict(names or {})}
    out = {"all": {"coverage": float(inside.double().mean()), "rows": int(t.shape[0])}}
    for value in sorted({int(v) for v in r.tolist()}):
        mask = r == value
        name = label.get(value, str(value))
        out[name] = {"coverage": float(inside[mask].double().mean()), "rows": int(mask.sum())}
    return out
