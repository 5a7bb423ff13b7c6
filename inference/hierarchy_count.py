"""Counting model evaluations: how much a query costs, the same way for every planner.

One *mechanism evaluation* is one local mechanism f_i (one ensemble member f_i^(k)) evaluated at
one parent assignment. :func:`count_evaluations` wraps the site mechanisms of the given models
for the duration of a ``with`` block and adds, at each outermost call of one of :data:`COUNTED`
(``forward``, ``loc_scale``, ``member_loc_scale``, a discrete site's ``logits``, a gated site's
mixture over its switch), the number of parent rows (the product of the input's leading dims)
times the members evaluated (K for an ensemble evaluated on shared parents, 1 for one evaluated
on member-paired parents, whose leading K dim is already counted). Calls made inside
a counted call (a member inside its ensemble, a clamped mechanism's wrapped one) are not counted
again. Fixed relations (e.g. ``q = q_prev + dq``) count like learned ones: they are sites of the
program. Gradients are not counted; a backward pass costs about as much as its forward pass.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from functools import wraps
from typing import Any

from models.checks import describe
from models.world import WorldModel

__all__ = ["COUNTED", "EvaluationCount", "count_evaluations"]

#: The mechanism methods that count as evaluations, those a mechanism has.
COUNTED = (
    "forward",
    "loc_scale",
    "member_loc_scale",
    "logits",
    "mixture_loc",
    "member_mixture_loc",
    "mixture_variance",
)
#: Where a member method takes ``paired`` when it is given by position.
_PAIRED_AT = {"member_loc_scale": 1, "member_mixture_loc": 2}


@dataclass
class EvaluationCount:
    """Mechanism evaluations counted so far (module docstring).

    Attributes:
        total: evaluations over all sites.
        by_site: site name -> evaluations.
    """

    total: int = 0
    by_site: Counter[str] = field(default_factory=Counter)
    _depth: int = 0

    def add(self, site: str, rows: int) -> None:
        """Add ``rows`` evaluations of ``site``."""
        self.total += rows
        self.by_site[site] += rows


def _rows(args: tuple[Any, ...], members: int) -> int:
    x = args[0] if args else None
    shape = getattr(x, "shape", None)
    if shape is None or len(shape) == 0:
        return members
    n = 1
    for s in shape[:-1]:
        n *= int(s)
    return n * members


def _wrap(
    count: EvaluationCount, site: str, method: Callable[..., Any], attr: str, size: int
) -> Callable[..., Any]:
    @wraps(method)
    def counted(*args: Any, **kwargs: Any) -> Any:
        if count._depth == 0:
            at = _PAIRED_AT.get(attr)
            paired = at is not None and bool(kwargs.get("paired", args[at] if len(args) > at else False))
            count.add(site, _rows(args, 1 if paired else size))
        count._depth += 1
        try:
            return method(*args, **kwargs)
        finally:
            count._depth -= 1

    return counted


@contextmanager
def count_evaluations(*models: WorldModel) -> Iterator[EvaluationCount]:
    """Count the mechanism evaluations of ``models`` inside the block (module docstring).

    Models that share mechanism modules (e.g. a :func:`inference.subgraph_model` and its source)
    may be given together; each module is wrapped once.

    Raises:
        ValueError: something that is not a :class:`models.WorldModel`.
    """
    count = EvaluationCount()
    patched: list[tuple[Any, str]] = []
    seen: set[int] = set()
    try:
        for model in models:
            if not isinstance(model, WorldModel):
                raise ValueError(f"count_evaluations counts WorldModels, got {describe(model)}")
            for site in model.graph.non_roots:
                mech = model.mechanism(site)
                if id(mech) in seen:
                    continue
                seen.add(id(mech))
                for attr in COUNTED:
                    method = getattr(mech, attr, None)
                    if method is None:
                        continue
                    object.__setattr__(mech, attr, _wrap(count, site, method, attr, int(mech.size)))
                    patched.append((mech, attr))
        yield count
    finally:
        for mech, attr in patched:
            mech.__dict__.pop(attr, None)
