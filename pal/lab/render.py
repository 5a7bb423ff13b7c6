"""The one renderer of reports: markdown for people, JSON for machines, PNG for figures.

Every experiment, benchmark and the demo go through :func:`markdown`, :func:`document` and
:func:`write`; no experiment formats its own output.
"""

from __future__ import annotations

import io
import math
import os
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pal.io.files import atomic_write_bytes, atomic_write_json
from pal.lab.report import VERDICTS, Cell, Report, Table, Target

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from pal.lab.runner import RunRecord

__all__ = [
    "FORMAT",
    "document",
    "jsonable",
    "markdown",
    "markdown_table",
    "save_figure",
    "tally",
    "targets_table",
    "write",
]

#: Format tag of the JSON document of a run.
FORMAT = "pal.report/1"


def jsonable(value: Any, path: str = "metrics") -> Any:
    """``value`` with tensors, arrays, numpy scalars and tuples turned into JSON types.

    Raises:
        ValueError: a NaN or infinite number, or an object JSON cannot hold; the message
            names its path (e.g. ``metrics.state.q_mse``). Undefined values must be ``None``.
    """
    if hasattr(value, "detach"):
        value = value.detach().cpu().numpy()
    if hasattr(value, "tolist") and not isinstance(value, (str, bytes)):
        value = value.tolist()
    if isinstance(value, dict):
        return {str(k): jsonable(v, f"{path}.{k}") for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v, f"{path}[{i}]") for i, v in enumerate(value)]
    if isinstance(value, float) and not math.isfinite(value):
        raise ValueError(f"{path} is {value}; reports hold finite numbers or None")
    if value is None or isinstance(value, (str, bool, int, float)):
        return value
    raise ValueError(f"{path} is a {type(value).__name__}, which JSON cannot hold")


def _cell(value: Cell) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "n/a"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value).replace("|", "\\|").replace("\n", " ")


def markdown_table(columns: Sequence[str], rows: Iterable[Sequence[Cell]]) -> str:
    """A GitHub markdown table; floats get 4 significant digits, ``None`` shows as ``n/a``."""
    lines = [
        "| " + " | ".join(_cell(c) for c in columns) + " |",
        "|" + "|".join("---" for _ in columns) + "|",
    ]
    lines += ["| " + " | ".join(_cell(v) for v in row) + " |" for row in rows]
    return "\n".join(lines)


#: How each verdict of :data:`pal.lab.report.VERDICTS` shows in markdown.
_SHOWN = {
    "met": "met",
    "not met": "**NOT met**",
    "not measured": "not measured",
    "not evaluated": "not evaluated",
}


def _verdict(target: Target) -> str:
    return _SHOWN[target.verdict]


def tally(targets: Iterable[Target]) -> str:
    """One sentence counting verdicts, e.g. ``"2 of 4 targets met (1 not met, 1 not evaluated)."``.

    Only ``met`` counts as met; not evaluated and not measured targets are counted apart.
    """
    targets = list(targets)
    counts = {v: sum(t.verdict == v for t in targets) for v in VERDICTS}
    rest = ", ".join(f"{counts[v]} {v}" for v in VERDICTS[1:] if counts[v])
    return f"{counts['met']} of {len(targets)} targets met" + (f" ({rest})." if rest else ".")


def _not_evaluated(targets: Iterable[tuple[str, Target]]) -> list[str]:
    """One line per target whose precondition failed: what it required."""
    return [
        f"- {f'{run}: ' if run else ''}`{t.name}` not evaluated: requires {t.precondition.reason}"
        for run, t in targets
        if t.precondition is not None and not t.evaluated
    ]


def targets_table(targets: Iterable[tuple[str, Target]], title: str = "Targets") -> Table:
    """One table of ``(run name, target)`` pairs with their verdicts; the caption tallies them."""
    targets = list(targets)
    rows = [
        (run, t.name, t.description, t.value, f"{t.direction} {t.threshold:.4g}", _verdict(t))
        for run, t in targets
    ]
    caption = "\n".join([tally(t for _, t in targets), *_not_evaluated(targets)])
    return Table(title, ("run", "target", "what", "value", "goal", "verdict"), rows, caption=caption)


def _table(table: Table, level: int = 3) -> list[str]:
    lines = [f"{'#' * level} {table.title}", ""] if table.title else []
    lines += [markdown_table(table.columns, table.rows), ""]
    if table.caption:
        lines += [table.caption, ""]
    return lines


def markdown(record: RunRecord | Report) -> str:
    """A run (or a bare report) as a markdown section: title, notes, tables, targets, figure names."""
    report = record if isinstance(record, Report) else record.report
    lines = [f"## {report.title}", ""]
    if report.notes:
        lines += [" ".join(report.notes), ""]
    for table in report.tables:
        lines += _table(table)
    if report.targets:
        rows = [
            (t.name, t.description, t.value, f"{t.direction} {t.threshold:.4g}", _verdict(t))
            for t in report.targets
        ]
        lines += ["Targets:", "", markdown_table(("target", "what", "value", "goal", "verdict"), rows), ""]
        lines += [tally(report.targets), *_not_evaluated(("", t) for t in report.targets), ""]
    if report.figures:
        lines += ["Figures: " + ", ".join(f"`{name}`" for name in report.figures), ""]
    if not isinstance(record, Report):
        lines.append(f"({record.kind} `{record.name}`, seed {record.seed}, {record.seconds:.1f} s)")
    return "\n".join(lines) + "\n"


def document(record: RunRecord) -> dict[str, Any]:
    """The run as one JSON-ready dict: metrics, tables, targets with verdicts, config, seed, versions."""
    report = record.report
    return {
        "format": FORMAT,
        "name": record.name,
        "kind": record.kind,
        "title": report.title,
        "notes": list(report.notes),
        "metrics": jsonable(dict(report.metrics)),
        "tables": [t.to_dict() for t in report.tables],
        "targets": [t.to_dict() for t in report.targets],
        "figures": list(record.figures),
        "config": record.config,
        "seed": record.seed,
        "versions": record.versions,
        "seconds": record.seconds,
    }


def save_figure(fig: Figure, path: str | os.PathLike[str], dpi: int = 120) -> Path:
    """Render ``fig`` to PNG atomically and close it."""
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight")
    plt.close(fig)
    return atomic_write_bytes(path, buf.getvalue())


def write(record: RunRecord, out_dir: str | os.PathLike[str]) -> dict[str, Path]:
    """Write ``NAME.json``, ``NAME.md`` and one ``NAME_FIG.png`` per figure to ``out_dir``.

    Returns:
        ``{"json": path, "markdown": path, FIG: path, ...}``.
    """
    out = Path(out_dir)
    paths = {"json": atomic_write_json(out / f"{record.name}.json", document(record))}
    paths["markdown"] = atomic_write_bytes(out / f"{record.name}.md", markdown(record).encode("utf-8"))
    for key, fig in record.report.figures.items():
        paths[key] = save_figure(fig, out / f"{record.name}_{key}.png")
    return paths
