"""Targets, tables and the reliability figure of object motion per regime (:mod:`.regimes`).

Targets (the pushing world, 90 % intervals, components counted separately):

- no-contact rows: median predicted sd <= 1 mm, and coverage in 85-95 %;
- contact rows (random pushes in C1, planned pushes in C2): coverage in 85-95 %.

Each target holds only with at least :data:`MIN_ROWS` rows in its regime; with fewer its
verdict is "not evaluated". The reliability figure puts each regime's empirical coverage
against the nominal level (:data:`.regimes.LEVELS`), one line per displacement form.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from pal.lab.report import Precondition, Table, Target

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["COVERAGE_RANGE", "MIN_ROWS", "SD_MAX_MM", "calibration_figure", "regime_table", "regime_targets"]

#: A regime's 90 % intervals should cover this share of its components ...
COVERAGE_RANGE = (0.85, 0.95)
#: ... and without contact the median predicted sd should be at most this, mm.
SD_MAX_MM = 1.0
#: A regime's targets count only with at least this many rows.
MIN_ROWS = 20


def _enough(stats: Mapping[str, Any], regime: str) -> Precondition:
    n = int(stats.get("rows", 0))
    return Precondition(n >= MIN_ROWS, f">= {MIN_ROWS} {regime} rows (had {n})")


def _coverage_targets(name: str, stats: Mapping[str, Any], regime: str, what: str) -> list[Target]:
    value, pre = stats.get("coverage"), _enough(stats, regime)
    lo, hi = COVERAGE_RANGE
    return [
        Target(
            f"{name}_coverage_low",
            value,
            lo,
            ">=",
            f"share of the true displacement components inside the 90 % predictive interval, {what}",
            pre,
        ),
        Target(
            f"{name}_coverage_high",
            value,
            hi,
            "<=",
            f"the same share, at most {hi:.0%} (wider intervals are underconfident), {what}",
            pre,
        ),
    ]


def regime_targets(summary: Mapping[str, Mapping[str, Any]], origin: str, prefix: str = "") -> list[Target]:
    """The targets of the module docstring on ``origin``'s rows of a :func:`.regimes.summarize` result.

    Args:
        summary: regime -> statistics (``"<origin> contact"``, ``"<origin> no contact"``).
        origin: ``"random"`` or ``"planned"``.
        prefix: put before every target's name (e.g. a form, ``"smooth_"``).

    Returns:
        no-contact sd, no-contact coverage (low, high), contact coverage (low, high).
    """
    empty: dict[str, Any] = {"rows": 0}
    off = summary.get(f"{origin} no contact", empty)
    on = summary.get(f"{origin} contact", empty)
    what = "random pushes (babbling)" if origin == "random" else "planned pushes"
    return [
        Target(
            f"{prefix}{origin}_no_contact_sd_mm",
            off.get("sd_median_mm"),
            SD_MAX_MM,
            "<=",
            f"median predicted sd of the displacement per component on no-contact rows of the {what}, mm",
            _enough(off, "no-contact"),
        ),
        *_coverage_targets(f"{prefix}{origin}_no_contact", off, "no-contact", f"no-contact rows, {what}"),
        *_coverage_targets(f"{prefix}{origin}_contact", on, "contact", f"contact rows, {what}"),
    ]


def regime_table(summaries: Mapping[str, Mapping[str, Mapping[str, Any]]], regimes: tuple[str, ...]) -> Table:
    """One row per regime and form: rows, 90 % coverage, median sd and |error| (mm).

    Args:
        summaries: form -> :func:`.regimes.summarize` result.
        regimes: the regimes to show, in order.
    """
    rows = []
    for regime in regimes:
        for form, summary in summaries.items():
            s = summary.get(regime, {"rows": 0})
            rows.append(
                [
                    regime,
                    form,
                    s["rows"],
                    s.get("coverage"),
                    s.get("sd_median_mm"),
                    s.get("abs_err_median_mm"),
                ]
            )
    return Table(
        "Held-out displacement per regime (90 % predictive interval, components counted separately)",
        ["regime", "form", "rows", "coverage", "median sd [mm]", "median |error| [mm]"],
        rows,
        caption=f"Targets: coverage {COVERAGE_RANGE[0]:.0%}-{COVERAGE_RANGE[1]:.0%} on every regime, "
        f"median sd <= {SD_MAX_MM:g} mm without contact; a regime with < {MIN_ROWS} rows is not evaluated.",
    )


def calibration_figure(
    summaries: Mapping[str, Mapping[str, Mapping[str, Any]]], regimes: tuple[str, ...], title: str
) -> Figure:
    """Reliability per regime: empirical coverage against the nominal level, one line per form.

    Args:
        summaries: form -> :func:`.regimes.summarize` result (with ``reliability``).
        regimes: one panel each.
        title: the figure's title.
    """
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(regimes), figsize=(3.6 * len(regimes), 3.5), squeeze=False)
    for ax, regime in zip(axes[0], regimes, strict=True):
        ax.plot([0, 1], [0, 1], color="k", lw=1, ls=":")
        ax.plot([0.9, 0.9], COVERAGE_RANGE, color="0.6", lw=5, alpha=0.6, solid_capstyle="butt")
        for (form, summary), colour in zip(summaries.items(), ("C0", "C3", "C2", "C1"), strict=False):
            s = summary.get(regime, {})
            curve = s.get("reliability")
            if not curve:
                continue
            levels = [float(k) for k in curve]
            ax.plot(levels, list(curve.values()), marker="o", color=colour, label=f"{form} (n={s['rows']})")
        ax.set(
            xlim=(0.4, 1.0),
            ylim=(0.0, 1.02),
            xlabel="nominal level",
            ylabel="empirical coverage",
            title=regime,
        )
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7, loc="lower right")
        else:
            ax.text(0.5, 0.5, "no rows", ha="center", va="center", transform=ax.transAxes)
    fig.suptitle(title)
    fig.tight_layout()
    return fig
