"""Typed world-model variables (thesis Eq. 4.28).

A :class:`Variable` is one node of the causal graph: an action, an observed state
descriptor or a latent quantity, with a dimension, optional bounds, a unit and a time
lag. ``lag=1`` marks the value of ``lag_of`` at the previous interaction step t-1.
"""

from __future__ import annotations

import math
import numbers
import urllib.parse
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

import numpy as np

from models.checks import check_int, describe

__all__ = ["RESERVED_NAMES", "Role", "Variable", "column_label", "site_name", "valid_name", "variable_name"]


#: Site names the Pyro program uses itself: the plate of units. Names starting with ``_``
#: are reserved too (Pyro's autoguides and pal's internal plates use them).
RESERVED_NAMES = frozenset({"units"})


def valid_name(name: Any) -> bool:
    """Whether ``name`` can name a variable (and its Pyro site).

    Any non-empty string of printable characters without leading or trailing whitespace:
    ``"q"``, ``"q.finger"``, ``"p44/42"``, ``"weight (kg)"`` and names made from MuJoCo
    names such as ``"act.robot:left_fingers"``, ``"q.arm/elbow"``, ``"q.left-knee"`` or
    ``"q.joint 1"``. Control characters, tabs and newlines are refused, and so are the
    reserved names: ``"units"`` (the plate) and names starting with ``_``. Any other text
    becomes a valid name through :func:`site_name`.
    """
    return (
        isinstance(name, str)
        and bool(name)
        and name.isprintable()
        and name == name.strip()
        and name not in RESERVED_NAMES
        and not name.startswith("_")
    )


def _escape(char: str) -> str:
    return "".join(f"%{b:02X}" for b in char.encode("utf-8"))


def site_name(label: Any) -> str:
    """The variable (site) name of a free-text column label; :func:`column_label` inverts it.

    The rule: ``%`` becomes ``%25``; control characters, leading and trailing whitespace,
    a leading ``_`` and the first letter of a reserved name are percent-encoded as their
    UTF-8 bytes (``%0A``, ``%20``, ``%5F``, ``%75nits``). Every other character is kept, so
    a label that is already a valid name and has no ``%`` is its own site name
    (``"p44/42"`` -> ``"p44/42"``, ``" age"`` -> ``"%20age"``, ``"50%"`` -> ``"50%25"``).
    The map is injective on strings. Integer labels (a DataFrame without column names) are
    written in decimal first (``3`` -> ``"3"``).

    Raises:
        ValueError: an empty label, or a label that is neither a str nor an int.
    """
    if isinstance(label, (int, np.integer)) and not isinstance(label, (bool, np.bool_)):
        label = str(int(label))
    if not isinstance(label, str):
        raise ValueError(f"column label {label!r} is not a str or an int; name the columns with strings")
    if not label:
        raise ValueError("column label '' is empty; every column needs a name")
    chars = ["%25" if c == "%" else c if c.isprintable() else _escape(c) for c in label]
    lead = len(label) - len(label.lstrip())
    trail = len(label) - len(label.rstrip())
    for i in [*range(lead), *range(len(label) - trail, len(label))]:
        chars[i] = _escape(label[i])
    if label[0] == "_" or label in RESERVED_NAMES:
        chars[0] = _escape(label[0])
    return "".join(chars)


def variable_name(label: Any) -> str:
    """The name rule of tables and edge lists: a valid name is kept, any other label is :func:`site_name`'d."""
    return label if valid_name(label) else site_name(label)


def column_label(name: str) -> str:
    """The column label that :func:`site_name` maps to ``name`` (percent-decoding)."""
    if not isinstance(name, str):
        raise ValueError(f"site name must be a str, got {describe(name)}")
    return urllib.parse.unquote(name, errors="strict")


class Role(StrEnum):
    """Architectural role of a variable (Eq. 4.28): V_act, V_obs or V_lat."""

    ACTION = "action"
    OBSERVED = "observed"
    LATENT = "latent"


def _number(value: Any) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))


def _as_bounds(value: Any, dim: int, name: str) -> tuple[tuple[float, ...], tuple[float, ...]] | None:
    if value is None:
        return None
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if not isinstance(value, Sequence) or isinstance(value, str) or len(value) != 2:
        raise ValueError(f"variable {name!r}: bounds must be a pair (low, high), got {value!r}")
    sides = []
    for side in value:
        if isinstance(side, np.ndarray):
            side = side.tolist()
        if _number(side):
            side = (float(side),) * dim
        else:
            if isinstance(side, str) or not isinstance(side, Sequence) or not all(_number(s) for s in side):
                raise ValueError(
                    f"variable {name!r}: bounds side {side!r} is not a number or a sequence of {dim} numbers"
                )
            side = tuple(float(s) for s in side)
            if len(side) != dim:
                raise ValueError(
                    f"variable {name!r}: bounds side has {len(side)} entries, expected {dim} (dim)"
                )
        if not all(math.isfinite(s) for s in side):
            raise ValueError(f"variable {name!r}: bounds must be finite, got {value!r}")
        sides.append(side)
    low, high = sides
    for i, (lo, hi) in enumerate(zip(low, high, strict=True)):
        if not lo < hi:
            raise ValueError(
                f"variable {name!r}: bounds low >= high in component {i} ({lo} >= {hi}); expected low < high"
            )
    return low, high


@dataclass(frozen=True)
class Variable:
    """One typed node of the world model.

    Args:
        name: site name, e.g. ``"q"``, ``"q.finger"`` or ``"q.arm/elbow"`` (see
            :func:`valid_name`); it is the public name of the Pyro sample site.
        role: ``"action"``, ``"observed"`` or ``"latent"``.
        dim: number of components of the value; values have shape ``(..., dim)``.
        bounds: ``(low, high)``, scalars or ``dim``-sequences with ``low < high``.
            Required for actions (their prior is ``Uniform(low, high)``).
        unit: physical unit, e.g. ``"rad"``; informational.
        lag: 0 for the current step t, 1 for the previous step t-1.
        lag_of: for ``lag=1``, the lag-0 variable whose previous value this is; rollouts
            copy that variable's prediction into this slot (Alg. 4.1, line 11).
    """

    name: str
    role: Role
    dim: int = 1
    bounds: tuple[tuple[float, ...], tuple[float, ...]] | None = None
    unit: str = ""
    lag: int = 0
    lag_of: str | None = None
    description: str = field(default="", compare=False)

    def __post_init__(self) -> None:
        if not valid_name(self.name):
            raise ValueError(
                f"variable name {self.name!r} is not valid; expected a non-empty string of printable "
                "characters without leading or trailing whitespace, not 'units' and not starting with '_' "
                "(e.g. 'q.finger' or 'q.arm/elbow'); models.variables.site_name maps any text to a valid name"
            )
        if not isinstance(self.role, str) or self.role not in [r.value for r in Role]:
            raise ValueError(
                f"variable {self.name!r}: role {self.role!r} is not one of {[r.value for r in Role]}"
            )
        object.__setattr__(self, "role", Role(self.role))
        object.__setattr__(self, "dim", check_int(f"variable {self.name!r}: dim", self.dim, minimum=1))
        object.__setattr__(
            self, "lag", check_int(f"variable {self.name!r}: lag", self.lag, minimum=0, maximum=1)
        )
        for key in ("unit", "description"):
            if not isinstance(getattr(self, key), str):
                raise ValueError(
                    f"variable {self.name!r}: {key} must be a str, got {describe(getattr(self, key))}"
                )
        if self.lag_of is not None and not isinstance(self.lag_of, str):
            raise ValueError(
                f"variable {self.name!r}: lag_of must be a variable name or None, got {describe(self.lag_of)}"
            )
        object.__setattr__(self, "bounds", _as_bounds(self.bounds, self.dim, self.name))
        if self.role is Role.ACTION:
            if self.bounds is None:
                raise ValueError(
                    f"action {self.name!r} has no bounds; actions need (low, high) for their "
                    "Uniform prior and for clipping"
                )
            if self.lag != 0:
                raise ValueError(f"action {self.name!r} must have lag 0, got lag {self.lag}")
        if self.lag == 0 and self.lag_of is not None:
            raise ValueError(f"variable {self.name!r}: lag_of is only meaningful with lag=1")

    @property
    def low(self) -> tuple[float, ...] | None:
        """Lower bounds, one per component, or None."""
        return None if self.bounds is None else self.bounds[0]

    @property
    def high(self) -> tuple[float, ...] | None:
        """Upper bounds, one per component, or None."""
        return None if self.bounds is None else self.bounds[1]

    def to_dict(self) -> dict[str, Any]:
        """JSON-compatible description."""
        return {
            "name": self.name,
            "role": self.role.value,
            "dim": self.dim,
            "bounds": None if self.bounds is None else [list(self.bounds[0]), list(self.bounds[1])],
            "unit": self.unit,
            "lag": self.lag,
            "lag_of": self.lag_of,
            "description": self.description,
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Variable:
        """Inverse of :meth:`to_dict`."""
        if not isinstance(data, Mapping):
            raise ValueError(f"variable entry must be a mapping, got {describe(data)}")
        known = {"name", "role", "dim", "bounds", "unit", "lag", "lag_of", "description"}
        unknown = {str(k) for k in data if k not in known}
        if unknown:
            raise ValueError(f"unknown variable fields {sorted(unknown)}; expected {sorted(known)}")
        if "name" not in data or "role" not in data:
            raise ValueError(f"variable entry {dict(data)!r} needs 'name' and 'role'")
        return cls(**dict(data))
