"""The summary of a sweep: mean ± sd per cell and metric (CSV, markdown) and a figure per target.

Every scalar number of a run's ``metrics`` (nested keys joined by dots; bools and lists left
out), every target value (``target.NAME``, over the runs where the target was evaluated), every
target's share of runs that met it (``met.NAME``: 1 met, 0 otherwise, so not evaluated and
not measured count as not met) and the run time (``seconds``) is summarised per cell over the
cell's finished runs: the mean and the sample standard deviation
``sd = sqrt(sum (x - mean)^2 / (n - 1))`` (``n/a`` for one run). Runs without a report are
listed as failed with their one-line error.
"""

from __future__ import annotations

import csv
import io
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pal.io.files import atomic_write_bytes, read_json
from pal.lab import render
from pal.lab.sweep_plan import SweepPlan

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["MANIFEST", "RUNS", "SweepResult", "summarise"]

#: The manifest of a sweep directory, and the sub-directory of its runs.
MANIFEST = "sweep.json"
RUNS = "runs"


@dataclass(frozen=True)
class SweepResult:
    """A finished sweep: its plan, the summary table and where everything was written.

    Attributes:
        plan: what was run.
        rows: the summary, one ``(cell settings, metric, n, mean, sd)`` per cell and metric.
        failed: run id -> ``(settings, seed, one-line error)`` of every run without a report.
        paths: ``{"manifest", "csv", "markdown", TARGET: png, ...}``.
        ran: ids of the runs executed by this call.
    """

    plan: SweepPlan
    rows: tuple[tuple[dict[str, Any], str, int, float | None, float | None], ...]
    failed: dict[str, tuple[dict[str, Any], int, str]]
    paths: dict[str, Path]
    ran: tuple[str, ...]


def _numbers(value: Any, prefix: str) -> dict[str, float]:
    """Scalar numbers of nested dicts, keys joined by dots (bools and lists left out)."""
    if isinstance(value, dict):
        out: dict[str, float] = {}
        for k, v in value.items():
            out.update(_numbers(v, f"{prefix}.{k}" if prefix else str(k)))
        return out
    if isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value):
        return {prefix: float(value)}
    return {}


def _values(document: Mapping[str, Any]) -> dict[str, float]:
    values = _numbers(document.get("metrics", {}), "")
    for t in document.get("targets", []):
        if t.get("value") is not None and t.get("verdict") != "not evaluated":
            values[f"target.{t['name']}"] = float(t["value"])
        values[f"met.{t['name']}"] = 1.0 if t.get("met") is True else 0.0
    values["seconds"] = float(document["seconds"])
    return values


def _mean_sd(xs: Sequence[float]) -> tuple[float | None, float | None]:
    if not xs:
        return None, None
    mean = sum(xs) / len(xs)
    if len(xs) < 2:
        return mean, None
    return mean, math.sqrt(sum((x - mean) ** 2 for x in xs) / (len(xs) - 1))


def _label(settings: Mapping[str, Any]) -> str:
    return ", ".join(f"{k}={v}" for k, v in settings.items()) or "base"


def _pm(mean: float | None, sd: float | None) -> str:
    if mean is None:
        return "n/a"
    return f"{mean:.4g} ± {sd:.2g}" if sd is not None else f"{mean:.4g} ± n/a"


Row = tuple[dict[str, Any], str, int, float | None, float | None]
Failed = dict[str, tuple[dict[str, Any], int, str]]


def _read_runs(sweep: SweepPlan, out: Path) -> tuple[list[list[dict[str, float]]], Failed, list[str]]:
    """Per cell, the values of each finished run; the failed runs; the target names in order."""
    per_cell: list[list[dict[str, float]]] = [[] for _ in sweep.cells]
    failed: Failed = {}
    targets: list[str] = []
    for r in sweep.runs:
        report = out / RUNS / f"{r.id}.json"
        error = out / RUNS / f"{r.id}.error.json"
        if report.is_file():
            document = read_json(report)
            per_cell[r.cell].append(_values(document))
            targets += [t["name"] for t in document.get("targets", []) if t["name"] not in targets]
        elif error.is_file():
            failed[r.id] = (r.settings, r.seed, str(read_json(error)["error"]))
        else:
            failed[r.id] = (r.settings, r.seed, "not run (interrupted?)")
    return per_cell, failed, targets


def _csv(sweep: SweepPlan, rows: Sequence[Row]) -> bytes:
    keys = [k for k, _ in sweep.grid]
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow([*keys, "metric", "n", "mean", "sd"])
    for settings, m, n, mean, sd in rows:
        writer.writerow(
            [
                *(settings[k] for k in keys),
                m,
                n,
                "" if mean is None else repr(mean),
                "" if sd is None else repr(sd),
            ]
        )
    return buf.getvalue().encode()


def _markdown(
    sweep: SweepPlan, rows: Sequence[Row], metrics: Sequence[str], n_ok: Sequence[int], failed: Failed
) -> str:
    cells = sweep.cells
    lines = [
        f"## Sweep of {sweep.kind} `{sweep.name}` ({sweep.base} config{', ' + ' '.join(sweep.sets) if sweep.sets else ''})",
        "",
        f"{len(cells)} cells × {len(sweep.seeds)} seeds ({', '.join(map(str, sweep.seeds))}): "
        f"{sum(n_ok)} of {len(sweep.runs)} runs finished, {len(failed)} failed. "
        "Each entry is mean ± sd (sample sd, n/a for one run) over the cell's finished runs; "
        "`met.NAME` is the share of runs that met target NAME (not evaluated counts as not met), "
        "`target.NAME` its value over the runs where it was evaluated.",
        "",
        render.markdown_table(
            ("metric", *(_label(s) for s in cells)),
            [("finished runs", *(f"{n}/{len(sweep.seeds)}" for n in n_ok))]
            + [(m, *(_pm(r[3], r[4]) for r in rows if r[1] == m)) for m in metrics],
        ),
        "",
    ]
    if failed:
        lines += [
            "### Failed runs",
            "",
            render.markdown_table(
                ("run", "settings", "seed", "error"),
                [(i, _label(s), seed, e) for i, (s, seed, e) in failed.items()],
            ),
            "",
            "Run them again with `--retry-failed`.",
            "",
        ]
    return "\n".join(lines)


def _figure(sweep: SweepPlan, rows: Sequence[Row], metrics: Sequence[str], name: str) -> Figure:
    """Mean ± sd of target ``name`` per cell."""
    from matplotlib.figure import Figure

    cells = sweep.cells
    m = f"target.{name}"
    stats = [
        next(r for r in rows if r[0] == s and r[1] == m) if m in metrics else (s, m, 0, None, None)
        for s in cells
    ]
    fig = Figure(figsize=(max(4.0, 1.2 * len(cells)), 3.2))
    ax = fig.add_subplot()
    xs = [i for i, s in enumerate(stats) if s[3] is not None]
    ax.errorbar(
        xs,
        [stats[i][3] for i in xs],
        yerr=[stats[i][4] or 0.0 for i in xs],
        fmt="o",
        capsize=4,
    )
    ax.set_xticks(range(len(cells)), [_label(s) for s in cells], rotation=20, ha="right")
    ax.set_xlim(-0.5, len(cells) - 0.5)
    ax.set_ylabel(name)
    ax.set_title(f"{sweep.name}: {name}, mean ± sd over {len(sweep.seeds)} seeds")
    return fig


def summarise(sweep: SweepPlan, out_dir: str | os.PathLike[str], *, ran: tuple[str, ...] = ()) -> SweepResult:
    """Read every run of ``sweep`` in ``out_dir`` and write its table (CSV, markdown) and figures.

    Args:
        sweep: the plan stored in ``out_dir``.
        out_dir: the sweep's directory; run ``ID`` is ``runs/ID.json`` (finished) or
            ``runs/ID.error.json`` (failed); a run with neither counts as failed (not run).
        ran: ids of the runs executed by the caller (kept in the result).
    """
    out = Path(out_dir)
    cells = sweep.cells
    per_cell, failed, targets = _read_runs(sweep, out)
    metrics = sorted({m for rows in per_cell for values in rows for m in values})
    rows: list[Row] = []
    for c, settings in enumerate(cells):
        for m in metrics:
            xs = [v[m] for v in per_cell[c] if m in v]
            mean, sd = _mean_sd(xs)
            rows.append((settings, m, len(xs), mean, sd))
    paths = {
        "manifest": out / MANIFEST,
        "csv": atomic_write_bytes(out / "summary.csv", _csv(sweep, rows)),
    }
    markdown = _markdown(sweep, rows, metrics, [len(p) for p in per_cell], failed)
    paths["markdown"] = atomic_write_bytes(out / "summary.md", markdown.encode("utf-8"))
    for name in targets:
        paths[name] = render.save_figure(_figure(sweep, rows, metrics, name), out / f"{name}.png")
    return SweepResult(sweep, tuple(rows), failed, paths, ran)
