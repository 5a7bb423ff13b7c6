"""Values of a world model's variables: ``(N, dim)`` tensors checked at the entry points.

:func:`as_values` validates a mapping name -> array (shape, dtype, finiteness, one N) and
:func:`check_action_bounds` refuses actions outside their bounds. :func:`module_key` maps a
variable name to the key of its mechanism in the model's ``ModuleDict``.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import torch
from torch import Tensor, nn

from models.checks import as_float_tensor, check_finite_tensor, check_mapping
from models.graph import CausalGraph
from models.tables import as_table, is_table
from models.variables import Role

__all__ = ["BOUNDS_TOLERANCE", "as_values", "check_action_bounds", "module_key"]

#: Relative tolerance of the action-bounds check, a few float32 ulps: a value v passes
#: when ``low - tol <= v <= high + tol`` with ``tol = BOUNDS_TOLERANCE * max(1, |bound|)``.
BOUNDS_TOLERANCE = 4 * torch.finfo(torch.float32).eps


_ESCAPED = {"%": "%25", ".": "%2E", ":": "%3A"}


def module_key(name: str) -> str:
    """The ``ModuleDict`` key of a variable's mechanism; one key per name (an injective map).

    ``torch`` module names may not contain ``.``. A name without ``:`` or ``%`` maps its dots
    to colons (``q.finger`` -> ``q:finger``, the key of every saved model); any other name
    (MuJoCo names such as ``act.robot:left_fingers``), or one whose key would shadow a
    ``ModuleDict`` attribute, is ``%`` followed by the name with ``%``, ``.`` and ``:``
    percent-encoded, so no two names share a key.
    """
    key = name.replace(".", ":")
    if ":" in name or "%" in name or hasattr(nn.ModuleDict, key):
        return "%" + "".join(_ESCAPED.get(c, c) for c in name)
    return key


def as_values(
    graph: CausalGraph,
    values: Mapping[str, Any] | None,
    n: int | None = None,
    what: str = "data",
    extra_dims: int = 0,
    dtype: torch.dtype | None = None,
) -> tuple[dict[str, Tensor], int | None]:
    """Validate a mapping name -> array of shape ``(N, dim)`` (plus ``extra_dims`` after N).

    ``values`` may also be a table (:class:`models.tables.Table`, a pandas DataFrame or a
    structured array): its columns named like the graph's variables are taken (1-d
    columns as ``(N, 1)``), the others left out.

    Floating tensors and arrays of any precision are converted to ``dtype`` (default:
    torch's default dtype, which is the model's); Python numbers and lists are accepted;
    integer, bool, string and object data are refused (see :func:`models.checks.as_float_tensor`).

    Returns:
        Float tensors of ``dtype`` and the common N (or ``n`` when ``values`` is empty).

    Raises:
        ValueError: not a mapping, unknown names, wrong dtype, rank or dim, no rows,
            mismatched N, NaN or inf.
    """
    out: dict[str, Tensor] = {}
    if values is not None and is_table(values):
        values = as_table(values, keep=set(graph.names)).values
    values = check_mapping(what, values, allow_none=True)
    for name, raw in values.items():
        graph.check_name(name, what=f"variable in {what}")
        var = graph[name]
        t = as_float_tensor(raw, f"{what}[{name!r}]", dtype)
        expected = f"(N, {', '.join(['T'] * extra_dims + [str(var.dim)])})"
        if t.ndim != 2 + extra_dims or t.shape[-1] != var.dim:
            hint = " (reshape a 1-d column with x[:, None])" if t.ndim == 1 + extra_dims else ""
            raise ValueError(f"{what}[{name!r}] has shape {tuple(t.shape)}, expected {expected}{hint}")
        if t.shape[0] == 0 or t.numel() == 0:
            raise ValueError(f"{what}[{name!r}] has shape {tuple(t.shape)}: no rows; expected at least one")
        if n is None:
            n = t.shape[0]
        elif t.shape[0] != n:
            raise ValueError(f"{what}[{name!r}] has {t.shape[0]} rows, expected {n} like the others")
        check_finite_tensor(f"{what}[{name!r}]", t)
        out[name] = t
    return out, n


def check_action_bounds(graph: CausalGraph, values: Mapping[str, Tensor], what: str = "values") -> None:
    """Refuse action values outside their bounds (up to :data:`BOUNDS_TOLERANCE`).

    Args:
        graph: the causal graph.
        values: name -> tensor whose last dim is the variable's dim; only actions are checked.
        what: the argument name for the message.

    Raises:
        ValueError: naming the site, the first offending value and the bounds.
    """
    for name, v in values.items():
        var = graph[name]
        if var.role is not Role.ACTION or not isinstance(v, Tensor):
            continue
        low = torch.tensor(var.low, dtype=v.dtype)
        high = torch.tensor(var.high, dtype=v.dtype)
        tol_low = BOUNDS_TOLERANCE * low.abs().clamp_min(1.0)
        tol_high = BOUNDS_TOLERANCE * high.abs().clamp_min(1.0)
        vd = v.detach()
        bad = (vd < low - tol_low) | (vd > high + tol_high)
        if bool(bad.any()):
            first = tuple(int(i) for i in torch.nonzero(bad)[0]) if vd.ndim else ()
            value = float(vd[first]) if first else float(vd)
            component = first[-1] if first else 0
            raise ValueError(
                f"{what}[{name!r}] has {int(bad.sum())} entries outside the action bounds "
                f"[{var.low[component]:g}, {var.high[component]:g}] (first: {value:g} at index {first}); "
                "actions must lie within their bounds"
            )
