"""Calibration of a world model's one-step predictive distributions on held-out data.

For every checked site ``X_i ~ Normal(loc_i(pa_i), scale_i(pa_i))`` the observed parents of
each row give the predictive Normal (:meth:`models.mechanisms.Mechanism.loc_scale`: sigma_i,
sigma_i(pa_i), or an ensemble's moment-matched mixture), and the observed ``x_i`` is scored
against it:

    nll      = mean_{rows, dims} [ 0.5 log(2 pi scale^2) + 0.5 ((x - loc) / scale)^2 ]    (nats)
    coverage = mean_{rows, dims} 1[ |x - loc| <= Phi^-1((1 + level) / 2) * scale ]
    mse      = mean_{rows, dims} (x - loc)^2,        mean_sd = mean_{rows, dims} scale

and ``reliability`` lists the coverage at several nominal levels (a calibrated model has
observed = nominal; an overconfident one observes less). Nothing is sampled.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import torch

from models.checks import check_float, check_names
from models.world import as_values, require_world_model

__all__ = ["RELIABILITY_LEVELS", "predictive_check"]

#: Default nominal levels of the reliability pairs.
RELIABILITY_LEVELS = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9)


def _level(name: str, value: Any) -> float:
    return check_float(name, value, minimum=0.0, maximum=1.0, min_open=True, max_open=True)


def predictive_check(
    model: Any,
    data: Mapping[str, Any],
    *,
    level: float = 0.9,
    sites: Sequence[str] | None = None,
    levels: Sequence[float] | None = None,
) -> dict[str, dict[str, Any]]:
    """NLL, interval coverage, MSE and reliability of each site's predictive Normal.

    Args:
        model: a :class:`models.WorldModel`.
        data: name -> ``(N, dim)`` held-out values (e.g. realized transitions); a checked
            site needs its own column and its parents' columns.
        level: nominal probability of the central interval for ``coverage``, in (0, 1).
        sites: non-roots to check; default every non-root whose columns are present.
        levels: nominal levels of ``reliability``, each in (0, 1); default
            :data:`RELIABILITY_LEVELS`.

    Returns:
        site -> ``{"nll": float (nats per unit and dim), "coverage": float (share of rows,
        per component, inside the central level interval), "mse": float (units squared),
        "mean_sd": float (units), "reliability": [(nominal, observed), ...], "level": float,
        "n": int}``.

    Raises:
        ValueError: not a WorldModel, bad data (see :func:`models.world.as_values`), an
            unknown, root or uncovered site, no site to check, or a level outside (0, 1).
    """
    model = require_world_model(model)
    level = _level("level", level)
    if levels is None:
        levels = RELIABILITY_LEVELS
    if isinstance(levels, (str, bytes)) or not isinstance(levels, Sequence) or not levels:
        raise ValueError(f"levels must be a non-empty sequence of numbers in (0, 1), got {levels!r}")
    nominal = [_level(f"levels[{i}]", v) for i, v in enumerate(levels)]
    graph = model.graph
    cols, n = as_values(graph, data, dtype=model.dtype)
    if n is None:
        raise ValueError("data is empty; predictive_check needs name -> (N, dim) columns")
    covered = [v for v in graph.non_roots if v in cols and all(p in cols for p in graph.parents(v))]
    if sites is None:
        chosen = covered
        if not chosen:
            raise ValueError(
                f"no site can be checked from columns {sorted(cols)}; a site needs its and its parents' columns"
            )
    else:
        chosen = check_names("sites", sites, allow_empty=False)
        for v in chosen:
            graph.check_name(v, what="site")
            if graph.is_root(v):
                raise ValueError(f"site {v!r} is a root; only non-roots have a predictive distribution")
            missing = [c for c in (v, *graph.parents(v)) if c not in cols]
            if missing:
                raise ValueError(f"cannot check site {v!r}: data has no column for {missing}")
    out: dict[str, dict[str, Any]] = {}
    with torch.no_grad():
        for v in chosen:
            pa = torch.cat([cols[p] for p in graph.parents(v)], -1)
            loc, scale = model.mechanism(v).loc_scale(pa)
            x = cols[v]
            z = ((x - loc) / scale).abs()
            half = torch.special.ndtri(torch.tensor([(1 + q) / 2 for q in [level, *nominal]], dtype=x.dtype))
            inside = [float((z <= h).to(x.dtype).mean()) for h in half]
            nll = -torch.distributions.Normal(loc, scale).log_prob(x)
            out[v] = {
                "nll": float(nll.mean()),
                "coverage": inside[0],
                "mse": float(((x - loc) ** 2).mean()),
                "mean_sd": float(scale.mean()),
                "reliability": list(zip(nominal, inside[1:], strict=True)),
                "level": level,
                "n": int(n),
            }
    return out
