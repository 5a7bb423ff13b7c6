"""Grounding a literal (thesis Eq. 6.9): the grade g_P(x_S(t), o_1..o_n) in [0, 1] of a predicate.

The grade of a literal is read from an :class:`~pal.language.world.Outcome` (or a plain mapping
of values): the predicate's support S_P (the variables of its argument constants) is selected
at the literal's time (``start``: index 0, ``end``: index -1), or, for a predicate with a window
w > 0, over the last w + 1 times up to it; the grounding map is applied to every sample at
once (so the uncertainty of the variables is carried by the samples), and its result is
checked: one grade per sample, finite, in [0, 1] (within 1e-6, then clamped). A negated
literal grades ``1 - g``; a conjunction multiplies grades.

User predicates are written with :func:`predicate`::

    @predicate(sorts=("object",), support="position")
    def high(values, constants):
        "the object is above 0.5 m."
        (o,) = constants
        return torch.special.ndtr((values[o.variable("position")][..., 2] - 0.5) / 0.05)

    signature.add_predicate(high)
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import torch
from torch import Tensor

from pal.language.signature import Constant, GroundingRangeError, LanguageError, PredicateDef, Signature
from pal.language.terms import Literal
from pal.language.world import Outcome

__all__ = [
    "RANGE_TOLERANCE",
    "MissingVariableError",
    "WindowError",
    "conjunction",
    "literal_grade",
    "predicate",
    "roles_support",
]

#: Grades within this distance outside [0, 1] are clamped; farther ones are an error.
RANGE_TOLERANCE = 1e-6


class WindowError(LanguageError):
    """A window predicate read at a time with a shorter history than its window."""


class MissingVariableError(LanguageError):
    """A predicate's support variable that the outcome (or values) does not hold at that time."""


def roles_support(
    roles: str | Sequence[str | Sequence[str]],
) -> Callable[[tuple[Constant, ...]], tuple[str, ...]]:
    """A support function from roles: the variables bound to those roles of the arguments.

    Args:
        roles: one role for every argument (``"position"``), or one role (or tuple of roles)
            per argument (``("position", ("position", "contact"))``).
    """

    def support(constants: tuple[Constant, ...]) -> tuple[str, ...]:
        per_arg = [roles] * len(constants) if isinstance(roles, str) else list(roles)
        if len(per_arg) != len(constants):
            raise LanguageError(
                f"support roles {roles!r} are for {len(per_arg)} arguments, got {len(constants)}"
            )
        out: list[str] = []
        for c, r in zip(constants, per_arg, strict=True):
            for role in (r,) if isinstance(r, str) else r:
                name = c.variable(role, "support")
                if name not in out:
                    out.append(name)
        return tuple(out)

    return support


def predicate(
    name: str | None = None,
    *,
    sorts: tuple[str, ...],
    support: str | Sequence[Any] | Callable[[tuple[Constant, ...]], tuple[str, ...]],
    window: int = 0,
    doc: str | None = None,
    signature: Signature | None = None,
) -> Callable[[Callable[..., Any]], PredicateDef]:
    """Decorator: the function ``ground(values, constants) -> grade`` becomes a :class:`PredicateDef`.

    Args:
        name: the predicate's name (default: the function's name).
        sorts: one sort per argument (``"object|body_part"`` allows either).
        support: a callable constants -> variable names, or roles (see :func:`roles_support`).
        window: steps of history the map reads (0: values ``(..., d)`` at one time; w > 0:
            paths ``(..., w + 1, d)`` ending at the literal's time).
        doc: one line for listings (default: the first line of the function's docstring).
        signature: when given, the predicate is also added to it.

    Returns:
        A decorator returning the :class:`PredicateDef` (the decorated name is bound to it).
    """
    if isinstance(window, bool) or not isinstance(window, int) or window < 0:
        raise LanguageError(f"window must be an int >= 0, got {window!r}")
    support_fn = support if callable(support) else roles_support(support)

    def wrap(fn: Callable[..., Any]) -> PredicateDef:
        if not callable(fn):
            raise TypeError(f"@predicate decorates a grounding function, got {type(fn).__name__}")
        text = doc if doc is not None else (fn.__doc__ or "").strip().splitlines()[0:1]
        line = text if isinstance(text, str) else (text[0] if text else "")
        p = PredicateDef(name or fn.__name__, tuple(sorts), support_fn, fn, window, line)
        if signature is not None:
            signature.add_predicate(p)
        return p

    return wrap


def _select(
    literal: Literal, p: PredicateDef, names: tuple[str, ...], source: Outcome | Mapping[str, Tensor]
) -> dict[str, Tensor]:
    """The support values at the literal's time: ``(..., d)``, or ``(..., w + 1, d)`` with a window."""
    w = p.window
    if isinstance(source, Outcome):
        steps = source.shape[2] - 1
        available = source.window() if w else source.at(literal.time)
        if w:
            end = 0 if literal.time == "start" else steps
            if w > end:
                raise WindowError(
                    f"{literal}: predicate {p.name} needs a window of {w} steps, but the history at "
                    f"{literal.time} has {end} (the plan has {steps} steps)"
                )
            available = {k: v[:, :, end - w : end + 1] for k, v in available.items()}
        missing_start = source.unknown_start
    else:
        available = dict(source)
        missing_start = frozenset()
        if w:
            for k in names:
                v = available.get(k)
                history = 0 if literal.time == "start" or v is None or v.ndim < 2 else v.shape[-2] - 1
                if v is not None and w > history:
                    raise WindowError(
                        f"{literal}: predicate {p.name} needs a window of {w} steps, but the values of "
                        f"{k!r} hold a history of {history} at {literal.time}"
                    )
            available = {k: v[..., -(w + 1) :, :] for k, v in available.items() if k in names}
    out = {}
    for k in names:
        if k not in available:
            why = (
                "has no start value: give it in Situations.values"
                if k in missing_start and (literal.time == "start" or w)
                else f"is not among the world's variables {sorted(available)}"
            )
            raise MissingVariableError(f"{literal}: predicate {p.name} reads {k!r}, which {why}")
        out[k] = available[k]
    return out


def _check_grade(literal: Literal, g: Any, batch: tuple[int, ...]) -> Tensor:
    if not isinstance(g, Tensor):
        try:
            g = torch.as_tensor(g, dtype=torch.float64)
        except (TypeError, ValueError, RuntimeError) as err:
            raise GroundingRangeError(
                f"{literal}: the grounding map of {literal.atom.name} returned {type(g).__name__}, expected a tensor: {err}"
            ) from None
    if tuple(g.shape) != batch:
        raise GroundingRangeError(
            f"{literal}: the grounding map of {literal.atom.name} returned shape {tuple(g.shape)}, "
            f"expected one grade per sample {batch}"
        )
    if not g.is_floating_point():
        g = g.to(torch.float64)
    bad = ~torch.isfinite(g) | (g < -RANGE_TOLERANCE) | (g > 1.0 + RANGE_TOLERANCE)
    if bool(bad.any()):
        index = tuple(int(i) for i in torch.nonzero(bad)[0])
        raise GroundingRangeError(
            f"{literal}: the grounding map of {literal.atom.name} returned {float(g[index])!r} at index "
            f"{index} ({int(bad.sum())} bad grades); grades must be finite and within [0, 1]"
        )
    return g.clamp(0.0, 1.0)


def literal_grade(literal: Literal, signature: Signature, source: Outcome | Mapping[str, Tensor]) -> Tensor:
    """The grade of ``literal`` (``1 - g`` when negated) from an outcome or values.

    Args:
        literal: the literal; its atom is checked against the signature.
        signature: the signature holding its predicate and constants.
        source: an :class:`Outcome` (grades ``(N, S)``), or name -> ``(..., d)`` values at one time
            (``(..., T + 1, d)`` paths for a window predicate; grades ``(...)``).

    Raises:
        UnknownPredicateError, UnknownConstantError, ArityError, SortError, NotAnActionError: from
            the signature. MissingVariableError, WindowError, GroundingRangeError.
    """
    if not isinstance(literal, Literal):
        raise TypeError(f"expected a Literal, got {type(literal).__name__}")
    p, constants = signature.predicate(literal.atom)
    names = tuple(p.support(constants))
    values = _select(literal, p, names, source)
    lead = 2 if p.window else 1
    shapes = [tuple(v.shape[:-lead]) for v in values.values()]
    try:
        batch = tuple(torch.broadcast_shapes(*shapes)) if shapes else ()
    except RuntimeError:
        raise LanguageError(
            f"{literal}: support values of shapes {shapes} do not share a batch shape"
        ) from None
    g = _check_grade(literal, p.ground(values, constants), batch)
    return 1.0 - g if literal.negated else g


def conjunction(
    literals: Sequence[Literal], signature: Signature, source: Outcome | Mapping[str, Tensor]
) -> Tensor | None:
    """The product of the literals' grades, or None for no literals."""
    out: Tensor | None = None
    for lit in literals:
        g = literal_grade(lit, signature, source)
        out = g if out is None else out * g
    return out
