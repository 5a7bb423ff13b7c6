"""Admissible parent sets and the data layout that structure learning works on.

Admissibility (thesis Eq. 4.30, footnote 15) restricts the candidate parents of X_i:

- actions are roots: pa(A) = {} ;
- no edge runs backwards in time: a lag-1 variable has no lag-0 parent;
- optional background knowledge: ``tiers`` (a parent sits in the same or an earlier
  tier than its child), ``forbidden`` and ``required`` edges.

Interventional rows are marked per variable: ``intervened[name][r]`` is True when X_name
was set by ``do`` in row r. Such a row carries no evidence about f_name (the mechanism
was cut), so the likelihood of X_name skips it; it still is evidence for X_name's children.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import Tensor

from models.checks import as_float_array, check_edges, check_mapping, describe
from models.graph import CausalGraph
from models.variables import Role, Variable

__all__ = ["StructureData", "admissible_parents", "as_variables"]


def as_variables(variables: CausalGraph | Sequence[Variable]) -> list[Variable]:
    """The variables of a graph, or a checked list of :class:`Variable`."""
    if isinstance(variables, CausalGraph):
        return list(variables.variables.values())
    if isinstance(variables, (str, bytes, Mapping)) or not isinstance(variables, Iterable):
        raise ValueError(f"expected a CausalGraph or a sequence of Variable, got {describe(variables)}")
    out = list(variables)
    for v in out:
        if not isinstance(v, Variable):
            raise ValueError(f"expected a CausalGraph or Variable instances, got {type(v).__name__}")
    CausalGraph(out)  # validates names and lag_of
    return out


def _edges(edges: Iterable[Any], names: set[str], what: str) -> set[tuple[str, str]]:
    out = set()
    for e in check_edges(what, edges):
        if e[0] not in names or e[1] not in names:
            raise ValueError(
                f"{what} edge {e!r} is not a (parent, child) pair of known variables {sorted(names)}"
            )
        out.add(e)
    return out


def admissible_parents(
    variables: CausalGraph | Sequence[Variable],
    *,
    tiers: Sequence[Sequence[str]] | None = None,
    forbidden: Iterable[tuple[str, str]] = (),
    required: Iterable[tuple[str, str]] = (),
) -> dict[str, tuple[str, ...]]:
    """Candidate parents of every variable under the role/time rules and background knowledge.

    Args:
        variables: a graph (its edges are ignored) or the variables.
        tiers: optional ordered groups of names; a parent must be in the same or an earlier
            tier. Names in no tier are unconstrained by tiers.
        forbidden: edges that may not appear.
        required: edges that must appear; each must itself be admissible.

    Returns:
        child -> admissible parents, in declaration order (empty for actions).

    Raises:
        ValueError: unknown names, a name in two tiers, or an inadmissible required edge.
    """
    vs = as_variables(variables)
    by_name = {v.name: v for v in vs}
    names = set(by_name)
    tier_of: dict[str, int] = {}
    if tiers is not None and (isinstance(tiers, (str, bytes, Mapping)) or not isinstance(tiers, Iterable)):
        raise ValueError(f"tiers must be a sequence of sequences of names, got {describe(tiers)}")
    for k, tier in enumerate(tiers or ()):
        if isinstance(tier, str):
            raise ValueError(f"tier {k} is the string {tier!r}; expected a sequence of names")
        if isinstance(tier, Mapping) or not isinstance(tier, Iterable):
            raise ValueError(f"tier {k} is {describe(tier)}; expected a sequence of names")
        for n in tier:
            if not isinstance(n, str) or n not in names:
                raise ValueError(f"tier {k} names unknown variable {n!r}; known: {sorted(names)}")
            if n in tier_of:
                raise ValueError(f"variable {n!r} is in tiers {tier_of[n]} and {k}; expected one tier")
            tier_of[n] = k
    banned = _edges(forbidden, names, "forbidden")
    out: dict[str, tuple[str, ...]] = {}
    for child in vs:
        cand = []
        if child.role is not Role.ACTION:
            for parent in vs:
                if parent.name == child.name or (parent.name, child.name) in banned:
                    continue
                if parent.lag == 0 and child.lag == 1:
                    continue
                tp, tc = tier_of.get(parent.name), tier_of.get(child.name)
                if tp is not None and tc is not None and tp > tc:
                    continue
                cand.append(parent.name)
        out[child.name] = tuple(cand)
    for p, c in _edges(required, names, "required"):
        if p not in out[c]:
            raise ValueError(
                f"required edge {p!r} -> {c!r} is not admissible (roles, lags, tiers or forbidden)"
            )
    return out


@dataclass(frozen=True)
class StructureData:
    """Standardised columns and per-variable evidence masks.

    Attributes:
        names: variable names in declaration order.
        x: ``(N, D)`` float64, every column standardised on the rows where its variable
            was not intervened on (D = total dim).
        slices: name -> columns of ``x``.
        rows: name -> ``(N,)`` bool, rows that are evidence about the variable's mechanism.
    """

    names: tuple[str, ...]
    x: Tensor
    slices: dict[str, slice]
    rows: dict[str, Tensor]

    @classmethod
    def build(
        cls,
        variables: Sequence[Variable],
        data: Mapping[str, Any],
        intervened: Mapping[str, Any] | None = None,
    ) -> StructureData:
        """Validate ``data`` (name -> ``(N, dim)``) and ``intervened`` (name -> ``(N,)`` bool)."""
        if not isinstance(data, Mapping):
            raise ValueError(f"data must be a mapping name -> (N, dim) array, got {type(data).__name__}")
        names = tuple(v.name for v in variables)
        missing = [n for n in names if n not in data]
        extra = [k for k in data if k not in names]
        if missing or extra:
            raise ValueError(f"data columns must match the variables; missing {missing}, unknown {extra}")
        cols, n, slices, start = [], None, {}, 0
        for v in variables:
            a = as_float_array(data[v.name], f"data[{v.name!r}]")
            if a.ndim != 2 or a.shape[1] != v.dim:
                hint = " (reshape a 1-d column with x[:, None])" if a.ndim == 1 else ""
                raise ValueError(f"data[{v.name!r}] has shape {a.shape}, expected (N, {v.dim}){hint}")
            if n is None:
                n = a.shape[0]
            elif a.shape[0] != n:
                raise ValueError(f"data[{v.name!r}] has {a.shape[0]} rows, expected {n} like the others")
            if not np.isfinite(a).all():
                raise ValueError(f"data[{v.name!r}] contains NaN or inf; expected finite values")
            cols.append(a)
            slices[v.name] = slice(start, start + v.dim)
            start += v.dim
        if n is None or n < 8:
            raise ValueError(f"structure learning needs at least 8 rows, got {n}")
        rows = {name: torch.ones(n, dtype=torch.bool) for name in names}
        for name, mask in check_mapping("intervened", intervened, allow_none=True).items():
            if not isinstance(name, str) or name not in rows:
                raise ValueError(f"intervened names unknown variable {name!r}; known: {list(names)}")
            m = mask.detach().cpu().numpy() if isinstance(mask, Tensor) else np.asarray(mask)
            if m.shape != (n,) or m.dtype != bool:
                raise ValueError(
                    f"intervened[{name!r}] has shape {m.shape} and dtype {m.dtype}, expected ({n},) bool"
                )
            rows[name] = torch.from_numpy(~m)
            if int(rows[name].sum()) < 8:
                raise ValueError(
                    f"{name!r} is intervened on in all but {int(rows[name].sum())} rows; need >= 8 free rows"
                )
        x = torch.from_numpy(np.concatenate(cols, 1))
        for name in names:
            x[:, slices[name]] = _standardise(x[:, slices[name]], rows[name])
        return cls(names, x, slices, rows)

    @property
    def n(self) -> int:
        """Number of rows N."""
        return self.x.shape[0]

    def columns(self, names: Sequence[str]) -> list[int]:
        """Column indices of ``names`` in ``x``, concatenated in the given order."""
        return [c for n in names for c in range(self.slices[n].start, self.slices[n].stop)]


def _standardise(block: Tensor, free_rows: Tensor) -> Tensor:
    """``block``'s columns centred and scaled by the mean and sd of their ``free_rows``, at any magnitude.

    A column whose sd is at most 1e-12 is only centred (it is constant). A column whose sd or
    mean is not finite (values near 1e200 square to inf) or whose sd falls below 1e-12 (values
    near 1e-200) is first divided by the power of two at its largest magnitude, so its shape,
    not its units, decides; the constant test is then relative to that size. Other columns
    are left bit for bit as the plain formula gives them.
    """
    free = block[free_rows]
    scale, centre = free.std(0), free.mean(0)
    ok = torch.isfinite(scale) & torch.isfinite(centre) & (scale > 1e-12)
    plain = (block - centre) / torch.where(ok, scale, torch.ones_like(scale))
    if bool(ok.all()):
        return plain
    _, exponent = torch.frexp(block.abs().amax(0))
    unit = torch.ldexp(torch.ones_like(scale), exponent)  # an exact division: a power of two
    block, free = block / unit, free / unit
    scale = free.std(0)
    scale = torch.where(scale > 1e-12, scale, torch.ones_like(scale))
    return torch.where(ok, plain, (block - free.mean(0)) / scale)
