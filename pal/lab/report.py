"""What every experiment and benchmark returns: metrics, tables and targets as data, figures.

A :class:`Report` holds no markdown and no JSON text: :mod:`pal.lab.render` turns
every report into both, so all experiments print, store and compare the same way.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["DIRECTIONS", "VERDICTS", "Cell", "Precondition", "Report", "Table", "Target"]

#: How a target's value compares with its threshold.
DIRECTIONS = ("<=", ">=", "<", ">")
#: Every verdict a target can have; only ``"met"`` counts as met.
VERDICTS = ("met", "not met", "not measured", "not evaluated")
Cell = str | int | float | bool | None


@dataclass(frozen=True)
class Precondition:
    """What must hold for a target's comparison to mean anything, and whether it held.

    E.g. ``Precondition(moved, "the object moved > 5 mm in an episode of each controller")``:
    a ratio to a baseline that never moved the object is 1.0 without either controller
    doing anything. When ``holds`` is false the target's verdict is ``"not evaluated"``,
    which counts as not met.

    Attributes:
        holds: whether the condition held in this run.
        reason: the condition in words (what was required), shown beside the verdict.
    """

    holds: bool
    reason: str

    def __post_init__(self) -> None:
        holds = self.holds.item() if hasattr(self.holds, "item") else self.holds  # numpy bool
        if not isinstance(holds, bool):
            raise ValueError(f"precondition holds={self.holds!r} is not a bool")
        if not isinstance(self.reason, str) or not self.reason:
            raise ValueError(f"precondition reason must be a non-empty str, got {self.reason!r}")
        object.__setattr__(self, "holds", holds)

    @classmethod
    def nonzero(cls, value: Any, what: str) -> Precondition:
        """The baseline of a ratio did something: ``value`` is finite and nonzero.

        ``value`` is the baseline's error, distance, time ..., e.g.
        ``Precondition.nonzero(persistence_mse, "the q MSE of persistence")``.

        ``None`` (the baseline was not run, e.g. a peer library not installed) holds: the
        target's value is then ``None`` as well, and its verdict "not measured".
        """
        if hasattr(value, "item") and getattr(value, "ndim", None) == 0:
            value = value.item()
        if value is None:
            return cls(True, f"{what} finite and nonzero (not measured)")
        number = isinstance(value, (int, float)) and not isinstance(value, bool)
        holds = number and math.isfinite(value) and value != 0
        return cls(
            bool(holds), f"{what} finite and nonzero (was {value:.4g})" if number else f"{what} a number"
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready fields."""
        return {"holds": self.holds, "reason": self.reason}


@dataclass(frozen=True)
class Target:
    """A measured value and the threshold it should meet.

    Attributes:
        name: short identifier, e.g. ``"realized_mae.state"``.
        value: the measured value (``None``: not measured in this run, e.g. a graph left out).
        threshold: the bound.
        direction: ``value <direction> threshold`` is the goal, one of :data:`DIRECTIONS`.
        description: what is measured, in words, with its unit.
        precondition: what must hold for the comparison to count (``None``: nothing); when
            it fails the verdict is ``"not evaluated"`` and the target is not met.
    """

    name: str
    value: float | None
    threshold: float
    direction: Literal["<=", ">=", "<", ">"]
    description: str = ""
    precondition: Precondition | None = None

    def __post_init__(self) -> None:
        for key in ("value", "threshold"):  # numpy and torch scalars become Python numbers
            v = getattr(self, key)
            if hasattr(v, "item") and getattr(v, "ndim", None) == 0:
                object.__setattr__(self, key, v.item())
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"target name must be a non-empty str, got {self.name!r}")
        if self.direction not in DIRECTIONS:
            raise ValueError(
                f"target {self.name!r}: direction {self.direction!r}, expected one of {DIRECTIONS}"
            )
        if isinstance(self.threshold, bool) or not isinstance(self.threshold, (int, float)):
            raise ValueError(f"target {self.name!r}: threshold {self.threshold!r} is not a number")
        if not math.isfinite(self.threshold):
            raise ValueError(f"target {self.name!r}: threshold {self.threshold!r} is not finite")
        if self.value is not None:
            if isinstance(self.value, bool) or not isinstance(self.value, (int, float)):
                raise ValueError(f"target {self.name!r}: value {self.value!r} is not a number or None")
            object.__setattr__(self, "value", float(self.value))
        object.__setattr__(self, "threshold", float(self.threshold))
        if self.precondition is not None and not isinstance(self.precondition, Precondition):
            raise ValueError(
                f"target {self.name!r}: precondition {self.precondition!r} is not a Precondition"
            )

    @property
    def evaluated(self) -> bool:
        """Whether the precondition (if any) held, so the comparison counts."""
        return self.precondition is None or self.precondition.holds

    @property
    def met(self) -> bool | None:
        """Whether the value meets the threshold.

        ``False`` when the precondition failed (not evaluated counts as not met), else
        ``None`` when there is no finite value.
        """
        if not self.evaluated:
            return False
        if self.value is None or not math.isfinite(self.value):
            return None
        v, t = self.value, self.threshold
        return {"<=": v <= t, ">=": v >= t, "<": v < t, ">": v > t}[self.direction]

    @property
    def verdict(self) -> str:
        """One of :data:`VERDICTS`: ``"not evaluated"`` when the precondition failed."""
        if not self.evaluated:
            return "not evaluated"
        return {True: "met", False: "not met", None: "not measured"}[self.met]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready fields, with ``met`` (true, false or null), the ``verdict`` and the precondition."""
        value = self.value if self.value is None or math.isfinite(self.value) else None
        return {
            "name": self.name,
            "value": value,
            "threshold": self.threshold,
            "direction": self.direction,
            "met": self.met,
            "verdict": self.verdict,
            "precondition": None if self.precondition is None else self.precondition.to_dict(),
            "description": self.description,
        }


def _check_cell(table: str, value: Any) -> Cell:
    if value is None or isinstance(value, (str, bool, int)):
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if hasattr(value, "item") and getattr(value, "ndim", 1) == 0:  # numpy / torch scalars
        return _check_cell(table, value.item())
    raise ValueError(
        f"table {table!r}: cell {value!r} of type {type(value).__name__} is not str, number or None"
    )


@dataclass(frozen=True)
class Table:
    """A table as data: a title, column names and rows of plain cells.

    Floats are shown with 4 significant digits; ``None`` (and non-finite floats) show as
    ``n/a``. Attributes: ``title``, ``columns`` (names), ``rows`` (one tuple per row, as
    many cells as columns), ``caption`` (a sentence under the table).
    """

    title: str
    columns: Sequence[str]
    rows: Sequence[Sequence[Any]]
    caption: str = ""

    def __post_init__(self) -> None:
        columns = tuple(str(c) for c in self.columns)
        if not columns:
            raise ValueError(f"table {self.title!r} has no columns")
        rows = []
        for i, row in enumerate(self.rows):
            row = tuple(row)
            if len(row) != len(columns):
                raise ValueError(
                    f"table {self.title!r}: row {i} has {len(row)} cells, expected {len(columns)} ({columns})"
                )
            rows.append(tuple(_check_cell(self.title, v) for v in row))
        object.__setattr__(self, "columns", columns)
        object.__setattr__(self, "rows", tuple(rows))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready fields."""
        return {
            "title": self.title,
            "columns": list(self.columns),
            "rows": [list(r) for r in self.rows],
            "caption": self.caption,
        }


@dataclass(frozen=True)
class Report:
    """The outcome of one experiment or benchmark run.

    Attributes:
        title: heading, e.g. ``"B1: sensorimotor transition prediction (thesis Table 5.7)"``.
        metrics: nested JSON-compatible numbers (str keys; lists, floats, ints, str, None).
        tables: tables as data, thesis numbers beside ours where the thesis reports them.
        targets: the run's targets with their verdicts.
        notes: sentences describing the setup, shown under the title.
        figures: name -> matplotlib ``Figure`` (not part of the JSON; written as PNG).
    """

    title: str
    metrics: Mapping[str, Any]
    tables: Sequence[Table] = ()
    targets: Sequence[Target] = ()
    notes: Sequence[str] = ()
    figures: Mapping[str, Figure] = field(default_factory=dict, compare=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "tables", tuple(self.tables))
        object.__setattr__(self, "targets", tuple(self.targets))
        object.__setattr__(self, "notes", tuple(self.notes))
        for kind, items, cls in (("table", self.tables, Table), ("target", self.targets, Target)):
            for item in items:
                if not isinstance(item, cls):
                    raise ValueError(f"report {self.title!r}: {kind} {item!r} is not a {cls.__name__}")
        names = [t.name for t in self.targets]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"report {self.title!r}: duplicate target names {dup}")
        if not isinstance(self.metrics, Mapping):
            raise ValueError(
                f"report {self.title!r}: metrics must be a mapping, got {type(self.metrics).__name__}"
            )

    def target(self, name: str) -> Target:
        """The target called ``name``."""
        for t in self.targets:
            if t.name == name:
                return t
        raise KeyError(
            f"report {self.title!r} has no target {name!r}; targets: {[t.name for t in self.targets]}"
        )
