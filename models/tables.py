"""Tables as world-model data: DataFrames, dicts of 1-d columns and arrays with column names.

A :class:`Table` holds named ``(N, dim)`` float64 columns. It is built from

* a pandas ``DataFrame`` (pandas is optional: it is recognised by its interface, never
  imported here), one column per label;
* a mapping label -> 1-d ``(N,)`` or 2-d ``(N, dim)`` array;
* an ``(N, d)`` array with ``columns=`` (d labels), or a numpy structured array.

Column labels are free text. Each becomes a site name by one rule: a label that is already
a valid name (:func:`models.variables.valid_name`) is kept as it is (``"p44/42"``,
``"weight (kg)"``); any other label goes through :func:`models.variables.site_name`, which
percent-encodes what a site name may not hold (``" age"`` -> ``"%20age"``, ``"units"`` ->
``"%75nits"``). :attr:`Table.labels` maps every site name back to its label, and two labels
that would share a site name are refused, so the map is reversible.

Values: numeric and bool columns become float64 (bool as 0/1); a pandas ``category`` column
becomes its integer codes ``0 .. K-1`` (:attr:`Table.categories` keeps the category labels);
NaN, inf and non-numeric columns are refused with the column named. Every query entry point
(``fit``, ``discover``, ``infer_state``, ``counterfactual``, ...) accepts a Table, a DataFrame
or a structured array wherever it takes name -> ``(N, dim)`` values; columns that are not
variables of the model are left out there.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from models.checks import describe
from models.variables import Role, Variable, variable_name

__all__ = ["Table", "as_table", "is_table"]


def _is_dataframe(value: Any) -> bool:
    return all(hasattr(value, a) for a in ("columns", "dtypes", "to_numpy", "iloc"))


def is_table(value: Any) -> bool:
    """Whether ``value`` is a :class:`Table`, a DataFrame or a numpy structured array."""
    return (
        isinstance(value, Table)
        or _is_dataframe(value)
        or (isinstance(value, np.ndarray) and value.dtype.names is not None)
    )


def _column(label: Any, raw: Any) -> tuple[np.ndarray, tuple[str, ...] | None]:
    """One column as ``(N, dim)`` float64 and its category labels (pandas ``category`` only)."""
    cats = None
    dtype = getattr(raw, "dtype", None)
    if dtype is not None and str(dtype) == "category":
        codes = np.asarray(raw.cat.codes, dtype=np.int64)
        if (codes < 0).any():
            raise ValueError(
                f"column {label!r} has {int((codes < 0).sum())} missing values (NaN); drop or impute them"
            )
        cats = tuple(str(c) for c in raw.cat.categories)
        arr = codes.astype(np.float64)
    else:
        if isinstance(raw, torch.Tensor):
            raw = raw.detach().cpu().numpy()
        arr = np.asarray(raw.to_numpy() if hasattr(raw, "to_numpy") else raw)
        if arr.dtype.kind == "b":
            arr = arr.astype(np.float64)
        elif arr.dtype.kind in "iuf":
            arr = arr.astype(np.float64)
        else:
            sample = next(iter(arr.reshape(-1)), None) if arr.size else None
            raise ValueError(
                f"column {label!r} is not numeric (dtype {arr.dtype}, e.g. {sample!r}); continuous "
                "sites take numbers, discrete ones integer codes 0..K-1 (or a pandas 'category' column)"
            )
    if arr.ndim == 1:
        arr = arr[:, None]
    if arr.ndim != 2:
        raise ValueError(f"column {label!r} has shape {arr.shape}, expected (N,) or (N, dim)")
    bad = ~np.isfinite(arr)
    if bad.any():
        rows = np.nonzero(bad.any(1))[0]
        raise ValueError(
            f"column {label!r} has {len(rows)} rows with NaN or inf (first row {int(rows[0])}); "
            "drop or impute them first"
        )
    return arr, cats


@dataclass(frozen=True)
class Table:
    """Named ``(N, dim)`` float64 columns with their original labels.

    Build one with :func:`as_table`. Iterating and indexing work like a mapping of site
    names, so a Table can stand wherever name -> ``(N, dim)`` values are taken.

    Attributes:
        values: site name -> ``(N, dim)`` float64 array, in column order.
        labels: site name -> the original column label.
        categories: site name -> category labels, for pandas ``category`` columns.
    """

    values: dict[str, np.ndarray]
    labels: dict[str, Any]
    categories: dict[str, tuple[str, ...]] = field(default_factory=dict)

    @property
    def names(self) -> tuple[str, ...]:
        """The site names, in column order."""
        return tuple(self.values)

    @property
    def n(self) -> int:
        """Rows N."""
        return next(iter(self.values.values())).shape[0]

    def __getitem__(self, name: str) -> np.ndarray:
        return self.values[name]

    def __iter__(self) -> Any:
        return iter(self.values)

    def __len__(self) -> int:
        return len(self.values)

    def __contains__(self, name: object) -> bool:
        return name in self.values

    def site(self, label: Any) -> str:
        """The site name of a column label."""
        for name, lab in self.labels.items():
            if lab == label:
                return name
        raise ValueError(f"no column labelled {label!r}; labels: {list(self.labels.values())}")

    def select(self, names: Sequence[str]) -> Table:
        """The columns ``names`` (site names or labels), in that order."""
        keys = [n if n in self.values else self.site(n) for n in names]
        return Table(
            {k: self.values[k] for k in keys},
            {k: self.labels[k] for k in keys},
            {k: c for k, c in self.categories.items() if k in keys},
        )

    def tensors(self, dtype: torch.dtype | None = None) -> dict[str, torch.Tensor]:
        """Site name -> ``(N, dim)`` tensor of ``dtype`` (default: torch's default dtype)."""
        dtype = torch.get_default_dtype() if dtype is None else dtype
        return {k: torch.as_tensor(v, dtype=dtype) for k, v in self.values.items()}

    def variables(
        self, roles: Mapping[str, Role | str] | None = None, role: Role | str = Role.OBSERVED
    ) -> list[Variable]:
        """One :class:`Variable` per column (``dim`` from its width), ``role`` unless ``roles`` names it.

        Actions need bounds: give them as ``Variable`` objects instead.
        """
        roles = dict(roles or {})
        unknown = sorted(k for k in roles if k not in self.values)
        if unknown:
            raise ValueError(f"roles name {unknown}, which are not columns; columns: {list(self.names)}")
        return [
            Variable(k, roles.get(k, role), dim=v.shape[1], description=str(self.labels[k]))
            for k, v in self.values.items()
        ]


def as_table(data: Any, columns: Sequence[Any] | None = None, keep: Any = None) -> Table:
    """``data`` as a :class:`Table` (module docstring for the inputs and the name rule).

    Args:
        data: a Table, DataFrame, mapping label -> ``(N,)`` / ``(N, dim)`` array, structured
            array, or ``(N, d)`` array (then ``columns`` is required).
        columns: the d labels of an ``(N, d)`` array.
        keep: optional collection of site names; other columns are left out before they are
            converted or checked (a model's variables among a wider table's columns).

    Raises:
        ValueError: a 2-d array without ``columns`` or with the wrong number of them, an
            empty table, columns of different lengths, NaN or inf, non-numeric columns,
            labels that are not str or int, or two labels with one site name.
    """
    if isinstance(data, Table) and columns is None:
        return data if keep is None else data.select([k for k in data.names if k in keep])
    if columns is not None:
        if not isinstance(data, (np.ndarray, torch.Tensor)) or data.ndim != 2:
            raise ValueError(f"columns= goes with an (N, d) array, got {describe(data)}")
        columns = list(columns)
        if len(columns) != data.shape[1]:
            raise ValueError(f"data has {data.shape[1]} columns but {len(columns)} labels were given")
        raw = {c: data[:, i] for i, c in enumerate(columns)}
        if len(set(map(repr, columns))) != len(columns):
            raise ValueError(f"column labels {columns} repeat a label")
    elif _is_dataframe(data):
        labels = list(data.columns)
        if len(set(map(repr, labels))) != len(labels):
            raise ValueError(f"DataFrame column labels {labels} repeat a label")
        raw = {c: data[c] for c in labels}
    elif isinstance(data, np.ndarray) and data.dtype.names is not None:
        raw = {c: data[c] for c in data.dtype.names}
    elif isinstance(data, Mapping):
        raw = dict(data)
    elif isinstance(data, (np.ndarray, torch.Tensor)):
        raise ValueError(
            f"an array of shape {tuple(data.shape)} has no column names; pass columns=[...] (one label per column)"
        )
    else:
        raise ValueError(
            f"expected a DataFrame, a mapping of columns or an (N, d) array with columns=, got {describe(data)}"
        )
    if keep is not None:
        raw = {label: col for label, col in raw.items() if variable_name(label) in keep}
    if not raw:
        raise ValueError("the table has no columns" + ("" if keep is None else f" named like {sorted(keep)}"))
    values, labels, cats, n = {}, {}, {}, None
    for label, col in raw.items():
        name = variable_name(label)
        if name in labels:
            raise ValueError(
                f"column labels {labels[name]!r} and {label!r} both map to the site name {name!r}"
            )
        arr, c = _column(label, col)
        if n is None:
            n = arr.shape[0]
        elif arr.shape[0] != n:
            raise ValueError(f"column {label!r} has {arr.shape[0]} rows, expected {n} like the others")
        values[name], labels[name] = arr, label
        if c is not None:
            cats[name] = c
    if n == 0:
        raise ValueError("the table has no rows")
    return Table(values, labels, cats)
