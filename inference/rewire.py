"""Editing the graph of a live world model and refitting only what changed.

:meth:`models.WorldModel.with_graph` copies every mechanism whose parent set is unchanged
("kept") and rewires the others: the first-layer weight columns of the parents that
remain are copied and new parents start at zero weight ("rewired"). :func:`rewire` does
that and then refits (Eq. 4.33) the rewired and new mechanisms, each on the rows that are
evidence about it: rows where the variable itself was set by ``do`` are left out.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from inference.fit import FIT_KWARGS, FitResult, fit
from models.checks import check_choice, check_int, check_keywords, check_mapping, check_names, check_seed
from models.graph import CausalGraph
from models.world import WorldModel, as_values, require_world_model

__all__ = ["RewireResult", "evidence_groups", "fit_with_evidence", "rewire"]

REFIT = ("changed", "all", "none")


@dataclass(frozen=True)
class RewireResult:
    """The edited model and what happened to each mechanism.

    Attributes:
        model: the new :class:`WorldModel` (the old one is unchanged).
        warm_start: variable -> ``"kept"``, ``"rewired"`` or ``"new"``.
        fits: one :class:`FitResult` per group of variables refitted on the same rows.
    """

    model: WorldModel
    warm_start: dict[str, str]
    fits: tuple[FitResult, ...]


def evidence_groups(
    names: list[str], n: int, intervened: Mapping[str, Any] | None
) -> list[tuple[list[str], np.ndarray]]:
    """Group variables by their evidence rows (the rows where they were not set by ``do``).

    Returns:
        ``[(names, rows)]`` with ``rows`` a ``(N,)`` bool mask; variables without a mask
        share the all-rows group.
    """
    names = check_names("names", names)
    n = check_int("n", n, minimum=1)
    intervened = check_mapping("intervened", intervened, allow_none=True)
    unknown = sorted(str(k) for k in intervened if k not in names)
    if unknown:
        raise ValueError(f"intervened names {unknown}, which are not among {names}")
    groups: dict[bytes, tuple[list[str], np.ndarray]] = {}
    for name in names:
        mask = np.ones(n, dtype=bool)
        if name in intervened:
            raw = intervened[name]
            cut = raw.detach().cpu().numpy() if isinstance(raw, torch.Tensor) else np.asarray(raw)
            if cut.shape != (n,) or cut.dtype != bool:
                raise ValueError(
                    f"intervened[{name!r}] has shape {cut.shape}, dtype {cut.dtype}; expected ({n},) bool"
                )
            mask = ~cut
        groups.setdefault(mask.tobytes(), ([], mask))[0].append(name)
    return list(groups.values())


def fit_with_evidence(
    model: WorldModel,
    data: Mapping[str, Any],
    variables: list[str],
    *,
    intervened: Mapping[str, Any] | None = None,
    **fit_kwargs: Any,
) -> tuple[FitResult, ...]:
    """:func:`inference.fit` of ``variables``, each on its own evidence rows."""
    model = require_world_model(model)
    fit_kwargs = check_keywords("fit_kwargs", fit_kwargs, [k for k in FIT_KWARGS if k != "variables"])
    cols, n = as_values(model.graph, data, what="data", dtype=model.dtype)
    if n is None:
        raise ValueError("data is empty; the refit needs name -> (N, dim) columns")
    out = []
    for names, rows in evidence_groups(variables, n, intervened):
        if int(rows.sum()) < 2:
            raise ValueError(f"{names} have {int(rows.sum())} evidence rows; need at least 2 to fit")
        mask = torch.from_numpy(rows)
        out.append(fit(model, {k: v[mask] for k, v in cols.items()}, variables=names, **fit_kwargs))
    return tuple(out)


def rewire(
    model: WorldModel,
    graph: CausalGraph,
    data: Mapping[str, Any] | None = None,
    *,
    intervened: Mapping[str, Any] | None = None,
    refit: str = "changed",
    seed: int = 0,
    **fit_kwargs: Any,
) -> RewireResult:
    """Put ``model`` on ``graph`` (warm start) and refit the mechanisms that changed.

    Args:
        model: the live model (left unchanged).
        graph: the edited graph, e.g. ``discover(...).graph``.
        data: name -> ``(N, dim)`` columns for the refit; None only with ``refit="none"``.
        intervened: name -> ``(N,)`` bool, rows where the variable was set by ``do``.
        refit: ``"changed"`` (rewired and new mechanisms), ``"all"`` or ``"none"``.
        seed: seeds the weights of new mechanisms and the refit (local generators).
        **fit_kwargs: passed to :func:`inference.fit` (``schedule=``, ``loss=``, ...).

    Returns:
        :class:`RewireResult`.
    """
    model = require_world_model(model)
    refit = check_choice("refit", refit, REFIT)
    seed = check_seed("seed", seed)
    fit_kwargs = check_keywords(
        "fit_kwargs", fit_kwargs, [k for k in FIT_KWARGS if k not in ("variables", "seed")]
    )
    if refit != "none" and data is None:
        raise ValueError("data is needed to refit; pass refit='none' to only rewire")
    new = model.with_graph(graph, seed=seed)  # new mechanisms draw from ``seed``, not the global RNG
    outcome = dict(new.provenance.get("warm_start", {}))
    targets = [v for v, how in outcome.items() if refit == "all" or how != "kept"]
    fits: tuple[FitResult, ...] = ()
    if refit != "none" and targets:
        fits = fit_with_evidence(new, data, targets, intervened=intervened, seed=seed, **fit_kwargs)
    return RewireResult(new, outcome, fits)
